#!/usr/bin/env bash
# Sourced by test.sh and demo.sh: create or reuse .venv, install bimgraph with its test extras,
# and the one system library the wheels cannot bring (Open3D needs libusb-1.0).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="${BIMGRAPH_VENV:-$ROOT/.venv}"

if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing libusb-1.0-0 (needed by Open3D)..." >&2
    (apt-get update -qq && apt-get install -y -qq libusb-1.0-0) >/dev/null
  elif command -v sudo >/dev/null && sudo -n true 2>/dev/null; then
    (sudo apt-get update -qq && sudo apt-get install -y -qq libusb-1.0-0) >/dev/null
  else
    echo "error: Open3D needs libusb-1.0. Run: sudo apt-get install libusb-1.0-0" >&2
    exit 1
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "creating $VENV..." >&2
  python3 -m venv "$VENV"
fi
# Reinstall only when pyproject.toml changed since the last install.
STAMP="$VENV/.bimgraph-installed"
if [ ! -f "$STAMP" ] || [ "$ROOT/pyproject.toml" -nt "$STAMP" ]; then
  echo "installing bimgraph and its dependencies into $VENV (first time: a few minutes)..." >&2
  "$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
  "$VENV/bin/python" -m pip install -q -e "$ROOT[test,plot]"
  touch "$STAMP"
fi
export PATH="$VENV/bin:$PATH"
