#!/usr/bin/env bash
# Regenerates the pictures in docs/images from the real cases (../shared/data/real; skipped with
# a message where absent) with this checkout's heartprep and heartsim (release build).
#   docs/images/holding-pat1.png   docs/user-guide.md "How the heart is held"
#   docs/images/window-hud.png     docs/runtime.md "Window mode": the window under Xvfb, driven by
#                                  xdotool (the mouse device pressed into the shipped phantom)
#   docs/images/section-phantom.png  docs/runtime.md "Section view": the shipped phantom cut open
set -euo pipefail
cd "$(dirname "$0")/.."
cmake --build --preset release --target heartprep heartsim >/dev/null
work=build/doc-images
mkdir -p "$work" docs/images

# The window: Xvfb of its own, heartsim with --device mouse, Ctrl + wheel until the probe
# touches the tissue, then P (the window as seen, HUD included).
if command -v Xvfb >/dev/null && command -v xdotool >/dev/null; then
  build/release/tools/heartprep build samples/phantom.nii.gz -o "$work/phantom.h5" --cavity 2 --anchor-border -q
  rm -f "$work"/phantom-*.png "$work/display"
  Xvfb -displayfd 3 -screen 0 800x600x24 -nolisten tcp 3>"$work/display" 2>/dev/null &
  xvfb=$!
  for _ in $(seq 100); do [ -s "$work/display" ] && break; sleep 0.1; done
  export DISPLAY=":$(head -1 "$work/display")"
  build/release/runtime/heartsim run "$work/phantom.h5" --backend cpu --size 800x560 --device mouse >"$work/window.log" 2>&1 &
  heartsim=$!
  wait_for() { for _ in $(seq "$2"); do grep -q "$1" "$work/window.log" && return 0; sleep 0.2; done; return 1; }
  xdotool search --sync --onlyvisible --name heartsim windowfocus --sync %1
  for _ in $(seq 80); do
    xdotool keydown ctrl click 4 keyup ctrl
    wait_for "touching the tissue" 8 && break
  done
  xdotool keydown ctrl click --repeat 3 --delay 200 4 keyup ctrl  # a little deeper
  # Orbit a quarter turn so the force arrow (towards the viewer at first) shows from the side.
  window=$(xdotool search --onlyvisible --name heartsim | head -1)
  xdotool mousemove --window "$window" 400 280 mousedown 1
  for x in $(seq 390 -10 280); do xdotool mousemove --window "$window" "$x" 280; sleep 0.05; done
  xdotool mouseup 1
  sleep 3
  xdotool key p
  wait_for "screenshot: wrote" 300
  xdotool key Escape
  wait "$heartsim" || true
  kill "$xvfb" 2>/dev/null || true
  mv "$(ls "$work"/phantom-*.png | head -1)" docs/images/window-hud.png
  echo "make-doc-images: docs/images/window-hud.png"
else
  echo "make-doc-images: Xvfb or xdotool is absent: docs/images/window-hud.png not regenerated" >&2
fi

# The section view: the shipped phantom at rest cut through its centre, facing the default view.
build/release/tools/heartprep build samples/phantom.nii.gz -o "$work/phantom.h5" --cavity 2 --anchor-border -q
build/release/runtime/heartsim run "$work/phantom.h5" --headless --steps 0 --size 640x560 --clip centre \
  --screenshot docs/images/section-phantom.png >/dev/null
echo "make-doc-images: docs/images/section-phantom.png"

real=../shared/data/real
if [ ! -d "$real" ]; then echo "make-doc-images: $real is absent: no picture regenerated" >&2; exit 0; fi
build/release/tools/heartprep build "$real/hvsmr16_pat1/training_axial_crop_pat1-label.nii.gz" -o "$work/pat1.h5" --cavity 2 -q
build/release/runtime/heartsim run "$work/pat1.h5" --headless --backend cpu --seconds 2 \
  --trajectory samples/probe_and_grab_pat1.csv --view left --size 900x700 --screenshot docs/images/holding-pat1.png
