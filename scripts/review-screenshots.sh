#!/usr/bin/env bash
# The review page as a person uses it, captured with headless Chromium into docs/images/review-*.png
# (export/node/review_flow.mjs, the same session tests/cli/test_gallery_serve.py runs): `photoshape gallery
# --serve` on the tiny demo, a PhotoShape turned in 3D, a render enlarged, graded with a key, the index
# filtered to the ungraded ones.
#
#   bash scripts/review-screenshots.sh              # builds the tiny demo in a temporary folder (~4 min on 2 cores)
#   bash scripts/review-screenshots.sh DATA_ROOT    # an existing collection: its best PhotoShape gets graded good
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
OUT=${OUT:-docs/images}
work=$(mktemp -d /tmp/photoshape-review-XXXX)
if [ $# -ge 1 ]; then
    export PHOTOSHAPE_DATA_ROOT=$1
else
    export PHOTOSHAPE_DATA_ROOT=$work/data
    "$VENV/bin/photoshape" demo --size tiny --seed 3 --no-evaluate > "$work/demo.log"
fi
unset PHOTOSHAPE_DATABASE_URL

"$VENV/bin/photoshape" gallery "$work/site" --serve --port 0 > "$work/serve.log" 2>&1 &
server=$!
trap 'kill -TERM $server 2>/dev/null || true; wait 2>/dev/null || true' EXIT
until grep -q "review: serving" "$work/serve.log"; do
    kill -0 $server 2>/dev/null || { cat "$work/serve.log"; exit 1; }
    sleep 1
done
url=$(grep -oE "http://127\.0\.0\.1:[0-9]+/" "$work/serve.log" | head -1)
"$VENV/bin/python" - "$url" "$OUT" <<'PY'
import sys

from photoshape_flow.export.browser import problems
from photoshape_flow.export.review_browser import SCREENSHOTS, review_flow

report = review_flow(sys.argv[1], screenshots=sys.argv[2], viewport=(1100, 760))
if report.get("error") or problems(report):
    sys.exit(f"review session failed: {report.get('error') or problems(report)}")
print("\n".join(f"{sys.argv[2]}/{name}" for name in SCREENSHOTS))
print("seconds per step:", report["seconds"])
PY
