#!/usr/bin/env bash
# The main job on the sample data: what `make demo` runs. Outputs go to $1 (default out/demo).
set -euo pipefail
out=${1:-out/demo}
softforce=.venv/bin/softforce
robot=sample_data/diamond/diamond.toml
mkdir -p "$out"
echo "== the robot model"
$softforce model show "$robot" --picture "$out/robot.png" --force
echo "== static equilibrium with the north and west cables pulled 5 mm"
$softforce model solve "$robot" --actuation 5,5,0,0 -o "$out/deformed.vtu" --force
echo "demo outputs in $out/"
