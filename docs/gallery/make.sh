#!/usr/bin/env bash
# Regenerate the README gallery from the configs, with the commands a user would type.
# Usage: bash docs/gallery/make.sh   (from the repository root, oceanlidar installed)
set -euo pipefail
cd "$(dirname "$0")/../.."
out=docs/gallery
oceanlidar preview configs/paper/example1.yaml --output $out/example1.gif
oceanlidar preview configs/paper/example2.yaml --output $out/example2.gif
oceanlidar preview configs/paper/example3.yaml --sample 0 --output $out/example3-mine.png
oceanlidar preview configs/paper/example3.yaml --sample 4 --output $out/example3-no-mine.png
oceanlidar preview configs/paper/example4.yaml --sample 0 --output $out/example4-mine.png
oceanlidar preview configs/paper/example4.yaml --sample 4 --output $out/example4-no-mine.png
oceanlidar preview configs/paper/mldc-strip.yaml --output $out/mldc-strip.png
oceanlidar preview configs/mldc-strip-300m.yaml --output $out/mldc-strip-300m.png
oceanlidar preview configs/conditioned.yaml --sample 0 --output $out/conditioned-0.png
oceanlidar preview configs/conditioned.yaml --sample 1 --output $out/conditioned-1.png
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
oceanlidar run configs/quickstart.yaml --output "$work/quickstart.zarr"
oceanlidar plot "$work/quickstart.zarr" --output $out/quickstart-statistics.png
oceanlidar run configs/detection-study.yaml --output "$work/detection-study.zarr"   # ~5 min
oceanlidar detect "$work/detection-study.zarr"
oceanlidar plot "$work/detection-study.detect.zarr" --output $out/detection-study.png
oceanlidar run configs/wind-trend.yaml --output "$work/wind-trend.zarr"   # ~7 min
oceanlidar detect "$work/wind-trend.zarr"
python -m benchmarks.wind_trend "$work/wind-trend.zarr" --png $out/wind-trend.png
