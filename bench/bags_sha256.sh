#!/bin/bash
# The `make bags` recipe run in the source tree DIR (default: this work tree) with the
# python environment's console scripts (VENV, default .venv), then the sha256 of the
# three example bags. Run it on two trees (e.g. `git archive` of two commits) to show a
# change leaves every bag byte-identical: bash bench/bags_sha256.sh DIR
set -e
VENV=${VENV:-.venv}
BIN=$(cd "$VENV/bin" && pwd)
cd "${1:-.}"
export PYTHONPATH=$PWD
rm -f bags/static_10s.mcap bags/paper_2019.mcap bags/temperature_cycle.mcap
"$BIN/qfa-sim" static --duration 10 --seed 1 --out bags/static_10s.mcap >/dev/null
"$BIN/qfa-sim" paper-2019 --seed 0 --out bags/paper_2019.mcap >/dev/null
"$BIN/qfa-sim" temperature-cycle --duration 3600 --seed 0 \
  --out bags/temperature_cycle.mcap >/dev/null
sha256sum bags/static_10s.mcap bags/paper_2019.mcap bags/temperature_cycle.mcap
