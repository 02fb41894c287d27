#!/usr/bin/env bash
# Bring up virtual CAN interfaces for hild's vcan rig (configs/arm6_vcan.yaml + `hild emulate`).
# Idempotent: an interface that already exists is only re-tuned and set up. Prints every command it runs.
set -euo pipefail

TXQUEUELEN=1000
FD=0
DOWN=0
IFACES=()

usage() {
    cat <<'EOF'
Usage: tools/vcan-setup.sh [--txqueuelen N] [--fd] [--down] [IFACE...]

Load the vcan kernel module and create, tune and bring up virtual CAN interfaces (default: vcan0).
Run as root (sudo). Safe to run again: existing interfaces are kept and only re-tuned.

  --txqueuelen N   transmit queue length (default 1000; the kernel default of 10 makes bursts of
                   frames fail with ENOBUFS "No buffer space available")
  --fd             CAN-FD frames (MTU 72) instead of classic CAN (MTU 16)
  --down           delete the interfaces instead
  -h, --help       this text

Then, in two shells:
  hild emulate configs/arm6_vcan.yaml
  hild run configs/arm6_vcan.yaml
EOF
}

run() {
    echo "+ $*"
    "$@"
}

die() {
    echo "vcan-setup: $*" >&2
    exit 1
}

while [[ $# -gt 0 ]]; do
    case "$1" in
        --txqueuelen)
            [[ $# -ge 2 && "$2" =~ ^[0-9]+$ && "$2" -gt 0 ]] || die "--txqueuelen needs a positive number"
            TXQUEUELEN="$2"
            shift 2
            ;;
        --fd) FD=1; shift ;;
        --down) DOWN=1; shift ;;
        -h | --help) usage; exit 0 ;;
        -*) usage >&2; die "unknown option $1" ;;
        *)
            [[ "$1" =~ ^[A-Za-z0-9_.-]{1,15}$ ]] || die "not an interface name: $1"
            IFACES+=("$1")
            shift
            ;;
    esac
done
[[ ${#IFACES[@]} -gt 0 ]] || IFACES=(vcan0)
[[ $EUID -eq 0 ]] || die "needs root to load modules and create interfaces: sudo $0 ${IFACES[*]}"
command -v ip >/dev/null || die "the 'ip' command (iproute2) is missing"

exists() {
    ip link show dev "$1" >/dev/null 2>&1
}

is_vcan() {
    ip -details link show dev "$1" | grep -qw vcan
}

if [[ $DOWN -eq 1 ]]; then
    for iface in "${IFACES[@]}"; do
        if exists "$iface"; then
            is_vcan "$iface" || die "$iface is not a vcan interface; not deleting it"
            run ip link delete dev "$iface"
        else
            echo "$iface: not present"
        fi
    done
    exit 0
fi

if [[ ! -d /sys/module/vcan ]]; then
    command -v modprobe >/dev/null || die "modprobe is missing and the vcan module is not loaded"
    run modprobe vcan || die "cannot load the vcan module (a kernel without CONFIG_CAN_VCAN? use the loopback rig, configs/arm6_can_loopback.yaml)"
fi

mtu=16
[[ $FD -eq 0 ]] || mtu=72
for iface in "${IFACES[@]}"; do
    if exists "$iface"; then
        is_vcan "$iface" || die "$iface exists and is not a vcan interface"
        echo "$iface: exists"
    else
        run ip link add dev "$iface" type vcan
    fi
    if [[ "$(cat "/sys/class/net/$iface/mtu")" != "$mtu" ]]; then
        run ip link set dev "$iface" down
        run ip link set dev "$iface" mtu "$mtu"
    fi
    run ip link set dev "$iface" txqueuelen "$TXQUEUELEN"
    run ip link set dev "$iface" up
    ip -details link show dev "$iface"
done
