#!/usr/bin/env bash
# Idempotent set-up on Debian/Ubuntu: system packages, a virtual environment with the CPU build of
# torch and the pinned stack, and the npm tools used by the export tests. `make demo`, `make test`
# and docker/Dockerfile all run this script, so every environment is built the same way.
#
#   VENV=.venv PYTHON=python3 bash scripts/setup.sh
#   SETUP_MODE=runtime bash scripts/setup.sh    # an image that runs the pipeline: no test tools
#
# Torch: `pip install torch==2.13.0` takes the local CPU wheel where the machine has one (PIP_FIND_LINKS);
# elsewhere it is installed from the CPU index (https://download.pytorch.org/whl/cpu) so pip never
# pulls the multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."

VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}
TORCH_VERSION=2.13.0
TORCH_CPU_INDEX=${TORCH_CPU_INDEX:-https://download.pytorch.org/whl/cpu}
SETUP_MODE=${SETUP_MODE:-dev}                 # dev: everything `make test` needs; runtime: the pipeline only
REQUIRED_APT=(libllvm19)                      # Mitsuba llvm variant: Debian 12's libllvm15 aborts on first render
OPTIONAL_APT=(postgresql chromium nodejs npm docker-compose sweethome3d-furniture)   # tests: PostgreSQL, gallery browser, glTF validator, compose, real shapes
EXTRAS="[dev]"
if [ "$SETUP_MODE" = runtime ]; then OPTIONAL_APT=(); EXTRAS=""; fi

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

missing_packages() {
    local pkg out=()
    for pkg in "$@"; do
        [ -n "$pkg" ] || continue
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || out+=("$pkg")
    done
    echo "${out[@]:-}"
}

# --- system packages -----------------------------------------------------------------------------
if command -v dpkg-query >/dev/null 2>&1; then
    need_required=$(missing_packages "${REQUIRED_APT[@]}")
    need_optional=$(missing_packages "${OPTIONAL_APT[@]:-}")
    # nodejs/npm may come from elsewhere (nodesource, nvm): only ask apt when the commands are missing
    if command -v node >/dev/null 2>&1; then need_optional=${need_optional//nodejs/}; fi
    if command -v npm >/dev/null 2>&1; then need_optional=${need_optional//npm/}; fi
    need_optional=$(echo "$need_optional" | xargs)
    if [ -n "$need_required$need_optional" ]; then
        if [ "$(id -u)" = 0 ]; then
            say "apt-get install $need_required $need_optional"
            apt-get update -qq
            # another apt (a user's, unattended-upgrades) may hold dpkg's lock: wait for it, not fail
            apt=(apt-get -o DPkg::Lock::Timeout=600)
            DEBIAN_FRONTEND=noninteractive "${apt[@]}" install -y -qq $need_required >/dev/null
            if [ -n "$need_optional" ]; then
                DEBIAN_FRONTEND=noninteractive "${apt[@]}" install -y -qq $need_optional >/dev/null \
                    || say "warning: could not install optional packages: $need_optional"
            fi
        else
            [ -n "$need_required" ] && { say "error: missing Debian package(s): $need_required (run: sudo apt-get install -y $need_required)"; exit 1; }
            say "note: optional Debian packages missing (some tests will skip): $need_optional"
        fi
    fi
else
    say "note: not a Debian system; install an LLVM >= 17 shared library for Mitsuba (e.g. libllvm19) yourself"
fi

# --- Python environment --------------------------------------------------------------------------
stamp="$VENV/.setup-stamp"
want=$( (cat pyproject.toml constraints.txt scripts/setup.sh; echo "$SETUP_MODE") | sha256sum | cut -d' ' -f1)
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    say "python environment up to date ($VENV)"
else
    # A venv left half-made by an interrupted set-up has a python but no pip: make it again.
    if [ -x "$VENV/bin/python" ] && ! "$VENV/bin/python" -m pip --version >/dev/null 2>&1; then
        say "$VENV has no pip (an interrupted set-up?): creating it again"; rm -rf "$VENV"
    fi
    [ -x "$VENV/bin/python" ] || { say "creating $VENV"; "$PYTHON" -m venv "$VENV"; }
    pip=("$VENV/bin/python" -m pip --disable-pip-version-check -q)
    if ! "$VENV/bin/python" -c "import torch, sys; sys.exit(torch.__version__.split('+')[0] != '$TORCH_VERSION')" 2>/dev/null; then
        if ls "${PIP_FIND_LINKS:-/nonexistent}"/torch-"$TORCH_VERSION"*cpu*.whl >/dev/null 2>&1; then
            say "installing torch $TORCH_VERSION (local CPU wheel)"
            "${pip[@]}" install "torch==$TORCH_VERSION"
        else
            say "installing torch $TORCH_VERSION from the CPU index $TORCH_CPU_INDEX"
            "${pip[@]}" install "torch==$TORCH_VERSION" --index-url "$TORCH_CPU_INDEX"
        fi
    fi
    say "installing photoshape_flow and pinned dependencies"
    "${pip[@]}" install -c constraints.txt -e ".$EXTRAS"
    # pydensecrf2 compiles the Krahenbuhl dense CRF (~1 min); the code falls back to its own mean-field without it.
    "${pip[@]}" install -c constraints.txt "pydensecrf2==1.1" \
        || say "warning: pydensecrf2 did not build; the fallback dense CRF will be used"
    echo "$want" > "$stamp"
fi

# --- npm tools (glTF validator, headless-browser gallery test) ----------------------------------
node_dir=src/photoshape_flow/export/node
if [ "$SETUP_MODE" != runtime ] && [ -f "$node_dir/package-lock.json" ] && command -v npm >/dev/null 2>&1; then
    lock_hash=$(sha256sum "$node_dir/package-lock.json" | cut -d' ' -f1)
    if [ ! -f "$node_dir/node_modules/.lock-hash" ] || [ "$(cat "$node_dir/node_modules/.lock-hash")" != "$lock_hash" ]; then
        say "npm ci in $node_dir"
        npm ci --silent --no-audit --no-fund --prefix "$node_dir" && echo "$lock_hash" > "$node_dir/node_modules/.lock-hash" \
            || say "warning: npm ci failed; glTF validation and browser tests will skip"
    fi
fi
say "ready: $VENV/bin/photoshape"
