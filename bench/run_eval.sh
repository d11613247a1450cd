#!/usr/bin/env bash
# Regenerate every evaluation result and figure under docs/figures/ (or $EVAL_OUT) with one
# command:
#
#   bench/run_eval.sh
#
# Needs the shared data beside the repository (../shared/data) or MOCAP_SHARED_DATA pointing
# at it. Descriptor vectors are cached in .eval-cache/ (delete it to start over); extra
# arguments are passed to every run (e.g. --workers 4, --no-figures).
set -euo pipefail

cd "$(dirname "$0")/.."
PYTHON="${PYTHON:-.venv/bin/python}"
SHARED="${MOCAP_SHARED_DATA:-../shared/data}"
OUT="${EVAL_OUT:-docs/figures}"

if [[ ! -d "$SHARED/bandai-ds1" || ! -d "$SHARED/cmu" ]]; then
    echo "run_eval.sh: no shared data in $SHARED (set MOCAP_SHARED_DATA)" >&2
    exit 2
fi

# Same as `mocap-index eval ...`.
eval_cmd() { "$PYTHON" -m app.evaluation eval "$@"; }

echo "== Bandai-Namco dataset 1: content and style, neighbours of another style =="
eval_cmd "$SHARED/bandai-ds1" \
    --labels-regex 'dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\d+' \
    --exclude-same style \
    --out "$OUT/bandai" "$@"

echo "== CMU: fine action labels, neighbours of another trial; format twins =="
eval_cmd "$SHARED/cmu" \
    --labels-tsv "$SHARED/cmu/labels.tsv" \
    --label-kind fine \
    --exclude-same trial \
    --out "$OUT/cmu" "$@"
