#!/usr/bin/env bash
# Print the path of a Python >= 3.12 interpreter, or fail with a clear message.
# Looks for 3.12 on PATH and in pyenv's versions directory, then for a newer 3.x in both.
# Set PYTHON=/path/to/python to choose one yourself.
set -u
ok() { "$1" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 12) else 1)' >/dev/null 2>&1; }
if [ -n "${PYTHON:-}" ]; then
  if ok "$PYTHON"; then echo "$PYTHON"; exit 0; fi
  echo "error: PYTHON=$PYTHON is not a Python >= 3.12 interpreter" >&2; exit 1
fi
root="${PYENV_ROOT:-$HOME/.pyenv}"
# The lock is resolved for 3.12, so a 3.12 is preferred; a newer one is the fallback.
candidates=$(command -v python3.12 2>/dev/null; ls -d "$root"/versions/3.12*/bin/python 2>/dev/null | sort -rV
  for n in python3.13 python3.14 python3 python; do command -v "$n" 2>/dev/null; done
  ls -d "$root"/versions/3.1[3-9]*/bin/python 2>/dev/null | sort -rV)
for p in $candidates; do
  if ok "$p"; then echo "$p"; exit 0; fi
done
cat >&2 <<MSG
error: scrppl needs Python >= 3.12 (ArviZ 1.x requires it), and none was found
       on PATH (python3.12, python3.13, python3.14, python3, python) or in $root/versions/.
       Install one (e.g. 'pyenv install 3.12') or run: make PYTHON=/path/to/python3.12 <target>
MSG
exit 1
