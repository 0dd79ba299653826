#!/usr/bin/env bash
# Submits a sharded `dc eval` run to SLURM: an array of N shards and the merge after them
# (docs/cluster.md). Prints the two job ids; the report lands in OUT/report.
#   scripts/slurm/submit-eval.sh N OUT [dc eval ARGS...] [--sbatch SBATCH_ARGS...]
# SBATCH_ARGS go to both jobs (--partition, --cpus-per-task, --time, --account).
set -euo pipefail
usage="usage: submit-eval.sh N OUT [dc eval ARGS...] [--sbatch SBATCH_ARGS...]"
shards="${1:?$usage}"
out="${2:?$usage}"
shift 2
[[ "$shards" =~ ^[1-9][0-9]*$ ]] || { echo "submit-eval.sh: N must be a positive number of shards, not \`$shards\`" >&2; exit 2; }
eval_args=()
sbatch_args=()
while [ $# -gt 0 ]; do
  if [ "$1" = --sbatch ]; then
    shift
    sbatch_args=("$@")
    break
  fi
  eval_args+=("$1")
  shift
done
here="$(cd "$(dirname "$0")" && pwd)"
out="$(realpath -m "$out")"
mkdir -p "$out"
array=$(sbatch --parsable "${sbatch_args[@]}" --array="0-$((shards - 1))" --chdir="$out" \
  --export="ALL,DC_OUT=$out" "$here/eval-shard.sbatch" "${eval_args[@]}")
array="${array%%;*}"
merge=$(sbatch --parsable "${sbatch_args[@]}" --dependency="afterok:$array" --chdir="$out" \
  --export="ALL,DC_OUT=$out,DC_SHARDS=$shards" "$here/merge.sbatch")
merge="${merge%%;*}"
echo "shards: job $array (array 0-$((shards - 1))); merge: job $merge; report: $out/report"
