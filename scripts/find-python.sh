#!/usr/bin/env bash
# Prints the full path of a Python interpreter named by a command, a path or a version (3.13, python3.13):
# the one on PATH if it runs, else the newest pyenv installation of that version (pyenv's shim for a
# version that is installed but not selected refuses to run). Exit 1, with one line, if there is none.
# scripts/install.sh resolves $PYTHON with it, scripts/check-pythons.sh each version of CAB_PYTHONS.
set -euo pipefail
want="${1:?usage: find-python.sh python3.13|3.13|/path/to/python}"
case "$want" in
  [0-9]*) name="python$want" ;;
  *) name="$want" ;;
esac
if command -v "$name" >/dev/null 2>&1 && exe=$("$name" -c 'import sys; print(sys.executable)' 2>/dev/null); then
  echo "$exe"
  exit 0
fi
# pythonX.Y (or X.Y): the newest pyenv installation X.Y.Z (plain CPython releases: no "t" or "-dev" builds)
ver="${name##*/}"; ver="${ver#python}"
if [[ "$ver" =~ ^3\.[0-9]+$ ]] && root=$( (pyenv root || echo "${PYENV_ROOT:-}") 2>/dev/null) && [ -d "$root/versions" ]; then
  for dir in $(ls -d "$root/versions/$ver".* 2>/dev/null | grep -E "/$ver\.[0-9]+$" | sort -V -r); do
    if [ -x "$dir/bin/python$ver" ]; then
      echo "$dir/bin/python$ver"
      exit 0
    fi
  done
fi
echo "no Python interpreter '$want': not on PATH, nor installed under pyenv" >&2
exit 1
