#!/usr/bin/env bash
# The installable product: build the wheel from the tracked files, install it into a fresh venv
# and run a smoke test from outside the source tree (bus-load, a short simulated demo run).
# Usage: tools/wheel_smoke.sh [PYTHON]      (default python3; what `make wheel-smoke` runs)
set -euo pipefail
python=${1:-python3}
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d "${TMPDIR:-/tmp}/ersac-wheel.XXXXXX")
trap 'rm -rf "$work"' EXIT
start=$SECONDS

mkdir "$work/src"   # only tracked files: a file git does not know is not in the wheel either
git -C "$root" ls-files -z | (cd "$root" && tar --null --ignore-failed-read -T - -cf -) | tar -C "$work/src" -xf -
"$python" -m pip wheel --quiet --no-deps --wheel-dir "$work/dist" "$work/src"
wheel=$(ls "$work"/dist/ersac_hil-*.whl)
echo "wheel-smoke: built $(basename "$wheel") in $((SECONDS - start)) s"

"$python" -m venv "$work/venv"
"$work/venv/bin/python" -m pip install --quiet --upgrade pip
"$work/venv/bin/python" -m pip install --quiet -c "$root/constraints.txt" "$wheel"
echo "wheel-smoke: installed into a fresh venv in $((SECONDS - start)) s"

cd "$work"   # nothing of the source tree is importable from here
export OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MUJOCO_GL=${MUJOCO_GL:-egl}
"$work/venv/bin/python" - <<'PY'
import protocol, firmware_sim, ersac_hil, sys
for pkg in (protocol, firmware_sim, ersac_hil):
    assert "/venv/" in pkg.__file__, f"{pkg.__name__} imported from {pkg.__file__}, not the wheel"
from protocol.can.devices import DEVICES, object_dictionary
from protocol.zenoh.jsonschema import SCHEMA_DIR, payload_schemas, render
assert all(object_dictionary(d) for d in DEVICES)         # EDS files shipped
assert all((SCHEMA_DIR / f"{n}.json").read_text() == render(s) for n, s in payload_schemas().items())
from firmware_sim.plant.physics import UBOT_XML
from firmware_sim.scenarios.bracing import PENDULUM_XML
from firmware_sim.scenarios.lifting import BOTTLE_XML
assert all(p.is_file() for p in (UBOT_XML, PENDULUM_XML, BOTTLE_XML))  # MJCF files shipped
from ersac_hil.dashboard.server import PAGE_FILES, PLOTLY_JS, STATIC
assert PLOTLY_JS.is_file() and all((STATIC / n).is_file() for n in PAGE_FILES)  # dashboard page shipped
print("wheel-smoke: package data present")
PY
"$work/venv/bin/ersac-hil" bus-load --check
"$work/venv/bin/ersac-hil" certs init "$work/certs" > /dev/null
"$work/venv/bin/python" -c "from ersac_hil.certs import role_of_config as r; assert r('$work/certs/observer.json5') == 'observer'"
"$work/venv/bin/ersac-hil" demo --episodes 3 --out "$work/demo"
test -s "$work/demo/summary.json"
echo "wheel-smoke: ok in $((SECONDS - start)) s"
