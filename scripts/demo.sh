#!/usr/bin/env bash
# The main job on the sample data: what `make demo` runs. Outputs go to $1 (default out/demo).
set -euo pipefail
out=${1:-out/demo}
softforce=.venv/bin/softforce
robot=sample_data/diamond/diamond.toml
recordings=sample_data/recordings
mkdir -p "$out"
echo "== the robot model (picture: $out/robot.png)"
$softforce model show "$robot" --picture "$out/robot.png" --force
echo "== static equilibrium with the north and west cables pulled 5 mm"
$softforce model solve "$robot" --actuation 5,5,0,0 -o "$out/deformed.vtu" --force
echo "== a sample recording (made by softforce simulate from sample_data/scenarios/)"
$softforce record info "$recordings/probes.mcap"
echo "== a synthetic recording: one and two probes on an actuated robot"
$softforce simulate sample_data/scenarios/probes.toml -o "$out/probes.mcap" --force
echo "== calibration from the markers of a recording (paper Algorithm 1)"
$softforce calibrate --robot "$robot" --recording "$recordings/markers.mcap" \
    -o "$out/calibration.json" --plot "$out/calibration_residual.png" --force
echo "demo outputs in $out/"
