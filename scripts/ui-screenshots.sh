#!/usr/bin/env bash
# The Prefect UI as a new user sees it after docs/operations.md section 2, captured with headless Chromium
# into docs/images/prefect-*.png: a local server on 127.0.0.1, `photoshape serve`, the nightly deployment
# run once on the tiny demo (its logs and artifacts), and its upcoming scheduled runs.
#
#   bash scripts/ui-screenshots.sh            # about 3 minutes on 2 cores; needs chromium (scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PORT=${PORT:-4321}
work=$(mktemp -d /tmp/photoshape-ui-XXXX)
export PREFECT_HOME=$work/prefect PREFECT_API_URL=http://127.0.0.1:$PORT/api PHOTOSHAPE_DATA_ROOT=$work/data
export PREFECT_SERVER_ANALYTICS_ENABLED=false DO_NOT_TRACK=1
unset PHOTOSHAPE_DATABASE_URL
command -v chromium >/dev/null || { echo "chromium is not installed (scripts/setup.sh installs it)"; exit 1; }

"$VENV/bin/prefect" server start --host 127.0.0.1 --port "$PORT" > "$work/server.log" 2>&1 &
server=$!
serve=""
trap 'kill $server $serve 2>/dev/null || true; wait 2>/dev/null || true' EXIT
until curl -sf "$PREFECT_API_URL/health" > /dev/null; do sleep 1; done

"$VENV/bin/python" -c "from photoshape_flow.demo import generate_demo; generate_demo('$work/data/inbox', 'tiny', seed=3)"
"$VENV/bin/photoshape" db upgrade
"$VENV/bin/photoshape" serve > "$work/serve.log" 2>&1 &
serve=$!
until grep -q "serving" "$work/serve.log"; do sleep 1; done
sleep 3
"$VENV/bin/prefect" deployment run photoshape-pipeline/nightly --param profile=tiny > "$work/run.txt"
run_id=$(grep -oE "UUID: [0-9a-f-]{36}" "$work/run.txt" | cut -d' ' -f2)
until "$VENV/bin/prefect" flow-run inspect "$run_id" 2>/dev/null | grep -qE "type=StateType.(COMPLETED|FAILED|CRASHED)"; do
    sleep 5
done
deployment_id=$("$VENV/bin/prefect" deployment inspect photoshape-pipeline/nightly | grep -oE "'id': '[0-9a-f-]{36}'" | head -1 | cut -d"'" -f4)

publish_id=$("$VENV/bin/python" - <<'PY'
from prefect.client.orchestration import get_client
from prefect.client.schemas.filters import FlowFilter, FlowFilterName
with get_client(sync_client=True) as client:
    print(client.read_flow_runs(flow_filter=FlowFilter(name=FlowFilterName(any_=["publish"])), limit=1)[0].id)
PY
)

shoot() {  # name, path
    chromium --headless=new --no-sandbox --hide-scrollbars --window-size=1440,960 --virtual-time-budget=15000 \
        --screenshot="docs/images/prefect-$1.png" "http://127.0.0.1:$PORT$2" > /dev/null 2>&1
    echo "docs/images/prefect-$1.png"
}
shoot deployments /deployments
shoot nightly-upcoming "/deployments/deployment/$deployment_id?tab=Upcoming"
shoot pipeline-run "/runs/flow-run/$run_id"
shoot publish-logs "/runs/flow-run/$publish_id"
shoot artifacts /artifacts
