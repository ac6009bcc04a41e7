#!/bin/bash
# Render a data set as a Slurm job array: array task i renders shard i/N into its own folder.
#   jid=$(sbatch --parsable --array=0-15 deploy/slurm_render_array.sh)
#   sbatch --dependency=afterok:$jid deploy/slurm_merge.sh
# Submit from the repository (set up with `make setup` on a file system the nodes share).
# PRESET (configs/dataset/<PRESET>.yaml) and PARTS (where the shard folders go) can be exported.
#SBATCH --job-name=bev-render
#SBATCH --cpus-per-task=16
#SBATCH --mem=32G
#SBATCH --time=24:00:00
#SBATCH --output=bev-render_%A_%a.log
set -euo pipefail
PRESET=${PRESET:-paper}
PARTS=${PARTS:-data/$PRESET.parts}
I=$SLURM_ARRAY_TASK_ID
N=$SLURM_ARRAY_TASK_COUNT
cd "$SLURM_SUBMIT_DIR"
# A rerun of a failed array task resumes from its folder's manifest.
.venv/bin/python -m dataset_tools generate --config "configs/dataset/$PRESET.yaml" --out "$PARTS/$I" \
    --shard "$I/$N" --workers "$SLURM_CPUS_PER_TASK" --no-progress
