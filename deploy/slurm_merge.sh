#!/bin/bash
# After every task of deploy/slurm_render_array.sh: merge the shard folders into one data set
# (checks that no frame is missing or twice), then fuse the labels, audit them and write the
# report (the stages after rendering, dataset_tools.pipeline).
#SBATCH --job-name=bev-merge
#SBATCH --cpus-per-task=16
#SBATCH --mem=32G
#SBATCH --time=6:00:00
#SBATCH --output=bev-merge_%j.log
set -euo pipefail
PRESET=${PRESET:-paper}
PARTS=${PARTS:-data/$PRESET.parts}
OUT=${OUT:-data/$PRESET}
cd "$SLURM_SUBMIT_DIR"
.venv/bin/python -m dataset_tools merge "$OUT" "$PARTS"/* --config "configs/dataset/$PRESET.yaml" \
    --workers "$SLURM_CPUS_PER_TASK" --no-progress
