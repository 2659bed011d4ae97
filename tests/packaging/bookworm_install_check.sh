#!/usr/bin/env bash
# Does `pip install crawlerd` stay safe on Raspberry Pi OS Bookworm? Builds a Debian bookworm root
# with apt's python3-numpy/-opencv/-av/-gpiozero (as the Pi has them), makes the venv the way
# docs/deploy.md says (--system-site-packages), runs a plain `pip install` (no --no-deps) of this
# checkout, then `pip check` and a replay. Pass: pip installs nothing that shadows apt's numpy or
# OpenCV, pip check is clean, and the replay runs on apt's libraries.
#   sudo tests/packaging/bookworm_install_check.sh [ARCH]     ARCH: amd64 (default, fast) or armhf (qemu)
# Needs root (mmdebstrap, chroot), Debian's mmdebstrap (and qemu-user-static for armhf), network to
# Debian and PyPI. Not run by `make test`: it builds a root file system (~2 minutes).
set -euo pipefail
arch=${1:-amd64}
src=$(cd "$(dirname "$0")/../.." && pwd)
root=${ROOT:-/tmp/crawlerd-bookworm-$arch}
command -v mmdebstrap >/dev/null || { apt-get update -qq && apt-get install -y -qq mmdebstrap >/dev/null; }
if [ ! -x "$root/usr/bin/python3" ]; then
  mirror=$(sed -n 's/^URIs:[[:space:]]*//p' /etc/apt/sources.list.d/*.sources 2>/dev/null | head -1)
  [ -n "$mirror" ] || mirror=$(awk '$1=="deb"{print $2; exit}' /etc/apt/sources.list)
  mmdebstrap --variant=apt --architectures="$arch" \
    --include=python3,python3-venv,python3-pip,python3-numpy,python3-opencv,python3-av,python3-gpiozero,ca-certificates \
    bookworm "$root" "deb $mirror bookworm main" >/dev/null
fi
cp /etc/resolv.conf "$root/etc/resolv.conf"
# a TLS-inspecting proxy's CA (this machine's bundle) must be trusted inside too
[ -f "${PIP_CERT:-}" ] && cp "$PIP_CERT" "$root/etc/ssl/certs/host-ca.crt" || true
rm -rf "$root/src" && mkdir -p "$root/src"
(cd "$src" && git ls-files -z | xargs -0 cp --parents -t "$root/src")
chroot "$root" /bin/bash -euo pipefail -c '
  export PIP_DISABLE_PIP_VERSION_CHECK=1
  if [ -f /etc/ssl/certs/host-ca.crt ]; then
    export PIP_CERT=/etc/ssl/certs/host-ca.crt SSL_CERT_FILE=/etc/ssl/certs/host-ca.crt REQUESTS_CA_BUNDLE=/etc/ssl/certs/host-ca.crt
  fi
  rm -rf /venv && python3 -m venv --system-site-packages /venv
  /venv/bin/pip install --quiet /src
  echo "--- installed into the venv (not from apt):"; ls /venv/lib/python3.11/site-packages | grep -iE "dist-info$" || true
  echo "--- pip check:"; /venv/bin/pip check
  /venv/bin/python -c "import numpy, cv2, av; print(\"numpy\", numpy.__version__, numpy.__file__); print(\"cv2\", cv2.__version__, cv2.__file__); print(\"av\", av.__version__)"
  /venv/bin/python -c "import numpy; assert numpy.__file__.startswith(\"/usr/lib/python3/dist-packages\"), numpy.__file__"
  cd /tmp && /venv/bin/python -m hw_sim render --out /tmp/s --name s --duration 1 --quiet >/dev/null
  /venv/bin/crawlerd --replay /tmp/s/s.h264 --max-frames 20
'
echo "bookworm ($arch) install check: OK"
