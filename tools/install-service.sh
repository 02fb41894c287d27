#!/usr/bin/env bash
# Install hild as a systemd service on a robot PC: user, venv, config, unit. Run as root; --dry-run shows the plan.
set -euo pipefail

REPO="$(cd "$(dirname "$0")/.." && pwd)"
PREFIX=/opt/hild
ETC=/etc/hild
UNIT_DIR=/etc/systemd/system
CONFIG="$REPO/configs/arm6_twin.yaml"
NAME=arm6
DRY_RUN=0
FORCE=0

usage() {
    cat <<'EOF'
Usage: tools/install-service.sh [--config FILE] [--prefix DIR] [--force] [--dry-run] [NAME]

Install hild as the systemd service hild@NAME, run as the unprivileged user hild:
  1. the system user and group hild
  2. a venv in PREFIX/venv (default /opt/hild/venv) with this checkout pip-installed into it
  3. /etc/hild/NAME.yaml from FILE (default configs/arm6_twin.yaml), with the model files it names copied
     beside it so its relative paths resolve; an existing /etc/hild/NAME.yaml is kept unless --force
  4. the unit /etc/systemd/system/hild@.service, then systemctl daemon-reload
Nothing is enabled or started: the script prints how.

  NAME           instance name, i.e. the config /etc/hild/NAME.yaml (default arm6)
  --config FILE  robot config to install as /etc/hild/NAME.yaml
  --prefix DIR   where the venv goes (default /opt/hild; the unit's ExecStart is adjusted to match)
  --force        overwrite an existing /etc/hild/NAME.yaml
  --dry-run      print every command instead of running it (no root needed)
  -h, --help     this text
EOF
}

while (($#)); do
    case "$1" in
        --config) CONFIG="$(cd "$(dirname "$2")" && pwd)/$(basename "$2")"; shift 2 ;;
        --prefix) PREFIX="$2"; shift 2 ;;
        --force) FORCE=1; shift ;;
        --dry-run) DRY_RUN=1; shift ;;
        -h|--help) usage; exit 0 ;;
        -*) echo "unknown option $1" >&2; usage >&2; exit 2 ;;
        *) NAME="$1"; shift ;;
    esac
done

if [[ ! "$NAME" =~ ^[A-Za-z0-9_.-]+$ ]]; then
    echo "NAME must be a plain instance name (letters, digits, _ . -), got: $NAME" >&2
    exit 2
fi
[[ -f "$CONFIG" ]] || { echo "no such config: $CONFIG" >&2; exit 2; }
if ((!DRY_RUN)) && [[ $(id -u) -ne 0 ]]; then
    echo "run as root (sudo), or with --dry-run to see what it would do" >&2
    exit 1
fi

run() {  # print, then run unless --dry-run
    local line; line="$(printf '%q ' "$@")"; echo "+ ${line% }"
    ((DRY_RUN)) || "$@"
}

echo "== 1. user and group hild"
if getent group hild >/dev/null; then echo "group hild exists"; else run groupadd --system hild; fi
if getent passwd hild >/dev/null; then
    echo "user hild exists"
else
    run useradd --system --gid hild --home-dir /var/lib/hild --no-create-home --shell /usr/sbin/nologin \
        --comment "hild robot bridge" hild
fi

echo "== 2. venv $PREFIX/venv"
run python3 -m venv "$PREFIX/venv"
run "$PREFIX/venv/bin/pip" install --quiet --upgrade pip
# A regular (not editable) install: the service does not depend on this checkout staying where it is.
run "$PREFIX/venv/bin/pip" install --quiet "$REPO"

echo "== 3. config $ETC/$NAME.yaml"
run install -d -m 0750 -o root -g hild "$ETC"
if [[ -e "$ETC/$NAME.yaml" && $FORCE -eq 0 ]]; then
    echo "$ETC/$NAME.yaml exists: kept (--force replaces it)"
else
    run install -m 0640 -o root -g hild "$CONFIG" "$ETC/$NAME.yaml"
fi
# Models are named relative to the config (robot.model, the twin's params.model): copy each one that is a file.
config_dir="$(dirname "$CONFIG")"
while read -r model; do
    if [[ -f "$config_dir/$model" ]]; then
        run install -D -m 0644 "$config_dir/$model" "$ETC/$model"
    fi
done < <(sed -nE 's/^[[:space:]]*model:[[:space:]]*([^[:space:]#,}]+).*/\1/p' "$CONFIG" | sort -u)

echo "== 4. unit $UNIT_DIR/hild@.service"
if [[ "$PREFIX" == /opt/hild ]]; then
    run install -m 0644 "$REPO/systemd/hild@.service" "$UNIT_DIR/hild@.service"
else
    echo "+ sed 's|/opt/hild/venv/bin/hild|$PREFIX/venv/bin/hild|' $REPO/systemd/hild@.service > $UNIT_DIR/hild@.service"
    ((DRY_RUN)) || sed "s|/opt/hild/venv/bin/hild|$PREFIX/venv/bin/hild|" "$REPO/systemd/hild@.service" \
        >"$UNIT_DIR/hild@.service"
fi
if [[ -d /run/systemd/system ]]; then
    run systemctl daemon-reload
else
    echo "systemd is not running here: run 'systemctl daemon-reload' on the robot PC"
fi
run "$PREFIX/venv/bin/hild" check "$ETC/$NAME.yaml"

cat <<EOF

Installed hild@$NAME$( ((DRY_RUN)) && echo " (dry run: nothing was changed)").
  Check the config:     $PREFIX/venv/bin/hild check $ETC/$NAME.yaml
  Start now and at boot: systemctl enable --now hild@$NAME
  State and loop:       systemctl status hild@$NAME      (STATUS: mode, cycle p99, overruns)
  Logs:                 journalctl -u hild@$NAME -f
  Stop (holds, releases the drives): systemctl stop hild@$NAME

CAN bring-up (real drives): hild opens can0 but does not configure it (that needs CAP_NET_ADMIN). Either
  - systemd-networkd: install $REPO/systemd/examples/80-can0.network as /etc/systemd/network/80-can0.network
    ([CAN] BitRate=1M), then: systemctl enable --now systemd-networkd
  - or a drop-in that runs 'ip link' as root before hild starts:
    install -D -m 0644 $REPO/systemd/examples/can0.conf /etc/systemd/system/hild@$NAME.service.d/can0.conf
    systemctl daemon-reload
Fast wake-ups (realtime.cpu_dma_latency_us: 0 in the config) need the device opened to the service user:
  install -m 0644 $REPO/systemd/examples/60-hild-cpu-dma-latency.rules /etc/udev/rules.d/ && udevadm trigger
Docs: $REPO/docs/operations.md ("Running as a service").
EOF
