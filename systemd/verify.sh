#!/usr/bin/env bash
# Run `systemd-analyze verify` on hild's unit, alone and with each drop-in example.
#
# verify also checks that ExecStart's program exists, and /opt/hild/venv/bin/hild only exists on an installed robot
# PC. So the check runs on a copy whose ExecStart points at a real hild executable (argument, default: the hild on
# PATH); every other line is the shipped text, unchanged. Exits non-zero on any finding.
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
hild="${1:-$(command -v hild || true)}"
if [[ -z "$hild" || ! -x "$hild" ]]; then
    echo "usage: systemd/verify.sh [PATH_TO_HILD]  (no executable hild found)" >&2
    exit 2
fi
hild="$(cd "$(dirname "$hild")" && pwd)/$(basename "$hild")"
if ! command -v systemd-analyze >/dev/null; then
    echo "systemd-analyze not found (Debian: apt-get install systemd)" >&2
    exit 2
fi

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

verify() {  # $1: label; the template is $work/hild@.service (+ drop-ins in $work/hild@.service.d/)
    local out
    # Verified as the instance hild@arm6 (the name only fills %i), found through the unit path set to $work.
    if ! out="$(SYSTEMD_UNIT_PATH="$work:" SYSTEMD_LOG_LEVEL=notice systemd-analyze verify --man=no hild@arm6.service 2>&1)" \
        || [[ -n "$out" ]]; then
        echo "FAIL $1:" >&2
        echo "$out" >&2
        return 1
    fi
    echo "ok   $1"
}

sed "s|^ExecStart=/opt/hild/venv/bin/hild |ExecStart=$hild |" "$here/hild@.service" >"$work/hild@.service"
grep -q "^ExecStart=$hild run /etc/hild/%i.yaml$" "$work/hild@.service" || {
    echo "hild@.service: ExecStart is not /opt/hild/venv/bin/hild run /etc/hild/%i.yaml" >&2
    exit 1
}
verify "hild@.service (ExecStart checked as $hild)"

status=0
for dropin in "$here"/examples/*.conf; do
    rm -rf "$work/hild@.service.d"
    mkdir -p "$work/hild@.service.d"
    cp "$dropin" "$work/hild@.service.d/"
    verify "hild@.service + examples/$(basename "$dropin")" || status=1
done
exit "$status"
