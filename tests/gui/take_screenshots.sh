#!/bin/sh
# Retake the README's screenshots of the wizard (docs/screenshots/): the wizard tests
# over the simulated station, each page grabbed as the operator sees it at 1366x768
# in a window manager's frame (Xvfb, openbox, ImageMagick's import; see
# tests/gui/helpers.py). Usage: sh tests/gui/take_screenshots.sh [pytest args]
# Needs: apt-get install -y xvfb openbox imagemagick, and the wizard's libraries (README).
set -e
cd "$(dirname "$0")/../.."
DISPLAY_NO=${SCREENSHOT_DISPLAY:-:97}
Xvfb "$DISPLAY_NO" -screen 0 1366x768x24 -nolisten tcp >/dev/null 2>&1 &
XVFB=$!
trap 'kill $WM $XVFB 2>/dev/null' EXIT INT TERM
sleep 1
DISPLAY="$DISPLAY_NO" openbox >/dev/null 2>&1 &
WM=$!
sleep 1
DISPLAY="$DISPLAY_NO" QT_QPA_PLATFORM=xcb CALSTATION_SCREENSHOTS=root \
  python -m pytest -q -m "slow or not slow" tests/gui/test_wizard_sm.py \
  tests/gui/test_wizard_pm.py tests/gui/test_wizard_arm.py tests/gui/test_wizard_urdf.py \
  tests/gui/test_wizard_accuracy.py \
  -k "not setup_reference_and_plan" "$@"
