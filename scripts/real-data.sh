#!/usr/bin/env bash
# Qualitative run on real data (paper section 6, "real data" column of docs/results.md):
#   shapes     Sweet Home 3D seating catalogs (Debian package sweethome3d-furniture) + ../shared/data/models
#   exemplars  the ABO product photos of ../shared/data/photos/abo (CC BY 4.0)
#   materials  ../shared/data/materials + the demo's procedural SVBRDFs (the real set has no leather,
#              fabric or real plastic, see ../shared/data/README.md)
#   envmaps    ../shared/data/envmaps + the demo's studio envmaps
# then every stage with the given profile and the gallery.
#
#   PHOTOSHAPE_DATA_ROOT=/tmp/real bash scripts/real-data.sh [PROFILE] [DEMO_COLLECTION_DIR]
#
# DEMO_COLLECTION_DIR is a generated demo collection (default: generate the small one into the data
# root). Nothing here is committed: the data stay where they are, the results go to the data root.
set -euo pipefail
cd "$(dirname "$0")/.."
PROFILE=${1:-small}
ROOT=${PHOTOSHAPE_DATA_ROOT:?set PHOTOSHAPE_DATA_ROOT to a scratch folder}
SHARED=${PHOTOSHAPE_SHARED_DATA:-../shared/data}
SH3D=/usr/share/sweethome3d/furniture
PS=.venv/bin/photoshape

[ -d "$SHARED/photos/abo" ] || { echo "real-data: no $SHARED/photos/abo (set PHOTOSHAPE_SHARED_DATA)" >&2; exit 2; }
DEMO=${2:-}
if [ -z "$DEMO" ]; then
  DEMO="$ROOT/demo-collection"
  [ -d "$DEMO/materials" ] || .venv/bin/python -c "
from pathlib import Path
from photoshape_flow.demo import generate_demo
generate_demo(Path('$DEMO'), size='small')"
fi

$PS db upgrade
# rejected inputs are reported; --allow-rejected lets the script go on with what was accepted
$PS ingest envmaps "$SHARED/envmaps" "$DEMO/envmaps" --allow-rejected
$PS ingest materials "$SHARED/materials" "$DEMO/materials" --allow-rejected
$PS ingest shapes "$SHARED/models/sweethome3d" --allow-rejected --license GPL-2.0-or-later \
  --attribution "Sweet Home 3D default furniture catalog, eTeks (Emmanuel Puybaret)"
$PS ingest shapes "$SHARED"/models/polyhaven_* --allow-rejected --license CC0-1.0 --attribution "Poly Haven (polyhaven.com)"
[ -d "$SH3D" ] && $PS ingest shapes "$SH3D" --allow-rejected --category chair,sofa,stool,bench  # catalogs carry their licences
$PS ingest exemplars "$SHARED/photos/abo" --allow-rejected --category chair --source abo \
  --license CC-BY-4.0 --attribution "Amazon Berkeley Objects, (c) Amazon.com, CC BY 4.0" \
  --source-url https://amazon-berkeley-objects.s3.amazonaws.com/index.html
for stage in coarse-alignment fine-alignment substances training-renders training inference fit publish; do
  $PS run "$stage" --profile "$PROFILE"
done
$PS gallery "$ROOT/gallery" --sheet "$ROOT/contact-sheet.png"
$PS status
