#!/usr/bin/env bash
# Adds X2Video Studio to this user's desktop menu: links the bundle's programs into ~/.local/bin and installs the
# .desktop entry and the icon under ~/.local/share (XDG_DATA_HOME). Run it from the unpacked bundle:
#     ./install.sh            (./install.sh --uninstall removes them again)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
data="${XDG_DATA_HOME:-$HOME/.local/share}"
bin="$HOME/.local/bin"
if [ "${1:-}" = "--uninstall" ]; then
  rm -f "$bin/x2video-studio" "$bin/x2video" "$data/applications/x2video-studio.desktop" "$data/icons/hicolor/scalable/apps/x2video-studio.svg"
  echo "removed X2Video Studio's menu entry and links"
  exit 0
fi
mkdir -p "$bin" "$data/applications" "$data/icons/hicolor/scalable/apps"
ln -sf "$here/x2video-studio" "$bin/x2video-studio"
ln -sf "$here/x2video" "$bin/x2video"
cp "$here/share/x2video-studio.svg" "$data/icons/hicolor/scalable/apps/x2video-studio.svg"
sed "s|^Exec=.*|Exec=\"$here/x2video-studio\" %f|; s|^TryExec=.*|TryExec=$here/x2video-studio|" \
  "$here/share/x2video-studio.desktop" > "$data/applications/x2video-studio.desktop"
command -v update-desktop-database >/dev/null && update-desktop-database "$data/applications" || true
echo "installed: $data/applications/x2video-studio.desktop (x2video-studio and x2video linked in $bin)"
