#!/bin/sh
# Install cellctl as a systemd service on the line PC (Debian, Python 3.11). Run as root from the
# repository:   sudo deploy/install.sh
# Idempotent: re-running updates the code and the unit but never overwrites /etc/cellctl/cell.toml.
set -eu

PREFIX=/opt/cellctl
REPO=$(cd "$(dirname "$0")/.." && pwd)

if [ "$(id -u)" != 0 ]; then
    echo "install.sh: run as root (sudo deploy/install.sh)" >&2
    exit 1
fi

apt-get install -y -qq python3-venv python3-dev gcc libc6-dev libgomp1 libusb-1.0-0

id cellctl >/dev/null 2>&1 || useradd --system --home-dir /var/lib/cellctl --shell /usr/sbin/nologin cellctl
usermod -a -G video,dialout cellctl

mkdir -p "$PREFIX"
cp -r "$REPO/cellctl" "$REPO/firmware_io" "$REPO/csrc" "$REPO/docs" "$REPO/pyproject.toml" "$REPO/setup.py" "$PREFIX/"
[ -x "$PREFIX/.venv/bin/python" ] || python3 -m venv "$PREFIX/.venv"
"$PREFIX/.venv/bin/python" -m pip install -q --upgrade pip
"$PREFIX/.venv/bin/python" -m pip install -q "$PREFIX"

mkdir -p /etc/cellctl
if [ ! -e /etc/cellctl/cell.toml ]; then
    cp "$REPO/deploy/cell-line.example.toml" /etc/cellctl/cell.toml
    echo "install.sh: edit /etc/cellctl/cell.toml and install the calibration as /etc/cellctl/calib.yaml"
fi

install -m 0644 "$REPO/deploy/99-cellctl-cameras.rules" /etc/udev/rules.d/99-cellctl-cameras.rules
udevadm control --reload-rules
udevadm trigger --subsystem-match=video4linux

install -m 0644 "$REPO/deploy/cellctl.service" /etc/systemd/system/cellctl.service
systemctl daemon-reload
systemctl enable cellctl.service
echo "install.sh: installed. Set the camera serials in /etc/udev/rules.d/99-cellctl-cameras.rules, then"
echo "            systemctl restart cellctl && journalctl -u cellctl -f"
