#!/bin/bash
# Run an umbra batch job as a Slurm job array: one array element per task of `umbra batch --plan`.
#
#   N=$(umbra batch JOB.toml --plan | wc -l)
#   sbatch --array=0-$((N - 1)) examples/batch/slurm.sh JOB.toml
#
# Task indices are 0-based, as --plan numbers them. A re-submitted array skips the tasks whose
# output is already up to date (outputs are written atomically), so resubmitting after a node
# failure redoes only the lost tasks; add --force to re-bake everything. To run fewer, larger
# array elements, use shards instead: --array=1-16 and `--shard $SLURM_ARRAY_TASK_ID/16`.
#SBATCH --job-name=umbra-batch
#SBATCH --cpus-per-task=4
#SBATCH --mem=8G
#SBATCH --output=umbra-batch-%A_%a.out
set -euo pipefail

JOB=${1:?usage: sbatch --array=0-N examples/batch/slurm.sh JOB.toml}
UMBRA=${UMBRA:-umbra}

exec "$UMBRA" batch "$JOB" --task "$SLURM_ARRAY_TASK_ID" --quiet --jobs 1
