#!/usr/bin/env bash
# The main job on the sample data, what `make demo` runs: calibrate -> material -> sense ->
# diagnose -> report on the shipped recordings (made by `softforce simulate` from
# sample_data/scenarios/; their truth files are read only to score the results at the end).
# Outputs go to $1 (default out/demo).
set -euo pipefail
out=${1:-out/demo}
softforce=.venv/bin/softforce
recordings=sample_data/recordings
# the coarse Diamond with the quadratic element: it does not lock (docs/locking.md)
robot=sample_data/diamond/diamond_p2.toml
mkdir -p "$out"
step() { printf '\n== %s\n' "$*"; }

step "the robot model (picture: $out/robot.png)"
$softforce model show "$robot" --picture "$out/robot.png" --force

step "the recordings (softforce simulate made them from sample_data/scenarios/)"
$softforce record info "$recordings/probes.mcap"

step "calibration: camera pose and cable inputs from the markers (paper Algorithm 1)"
$softforce calibrate --robot "$robot" --recording "$recordings/markers.mcap" \
    -o "$out/calibration.json" --plot "$out/calibration_residual.png" --force

step "material: Young's modulus from a known load (frame 2 of probes.mcap: a gauged 0.25 N push)"
$softforce calibrate --material --robot "$robot" --calibration "$out/calibration.json" \
    --recording "$recordings/probes.mcap" --frames 2:3 --reference-frames 0:1 \
    --load-point=-0.058,46.937,88.619 --load-n 0,-0.1527,-0.1979 \
    -o "$out/calibration_material.json" --force

# one frame per static state here (a camera gives 30): six FE updates let each frame settle
step "sensing: where the probes touch the robot and how hard (Algorithms 2-3, eq. 10-14)"
$softforce sense "$recordings/probes.mcap" --robot "$robot" \
    --calibration "$out/calibration_material.json" --tare 1 --updates 6 -o "$out/sense" --force

step "diagnosis: what the model leaves out (a concealed effect in diagnose_slack.mcap)"
$softforce diagnose "$recordings/diagnose_slack.mcap" --robot "$robot" \
    --calibration "$out/calibration.json" -o "$out/diagnose" --force

step "reports (HTML pages and PNG figures)"
$softforce report "$out/sense" --force
$softforce report "$out/diagnose" --force

step "scored against the truth files"
.venv/bin/python scripts/demo_summary.py "$out"
