#!/usr/bin/env bash
# Submits a sharded run to SLURM: an array of N shards of `dc eval ...` or `dc study
# solvers|budget ...`, and the merge after them (docs/cluster.md). Prints the two job ids; the
# report lands in OUT/report.
#   scripts/slurm/submit.sh N OUT eval|study ARGS... [--sbatch SBATCH_ARGS...]
# SBATCH_ARGS go to both jobs (--partition, --cpus-per-task, --time, --account).
set -euo pipefail
usage="usage: submit.sh N OUT eval|study ARGS... [--sbatch SBATCH_ARGS...]"
shards="${1:?$usage}"
out="${2:?$usage}"
shift 2
[[ "$shards" =~ ^[1-9][0-9]*$ ]] || { echo "submit.sh: N must be a positive number of shards, not \`$shards\`" >&2; exit 2; }
case "${1:-}" in
  eval | study) ;;
  *) echo "submit.sh: the command must be \`eval ...\` or \`study solvers|budget ...\`, not \`${1:-}\`" >&2; exit 2 ;;
esac
run_args=()
sbatch_args=()
while [ $# -gt 0 ]; do
  if [ "$1" = --sbatch ]; then
    shift
    sbatch_args=("$@")
    break
  fi
  run_args+=("$1")
  shift
done
here="$(cd "$(dirname "$0")" && pwd)"
out="$(realpath -m "$out")"
mkdir -p "$out"
array=$(sbatch --parsable "${sbatch_args[@]}" --array="0-$((shards - 1))" --chdir="$out" \
  --export="ALL,DC_OUT=$out" "$here/shard.sbatch" "${run_args[@]}")
array="${array%%;*}"
merge=$(sbatch --parsable "${sbatch_args[@]}" --dependency="afterok:$array" --chdir="$out" \
  --export="ALL,DC_OUT=$out,DC_SHARDS=$shards" "$here/merge.sbatch")
merge="${merge%%;*}"
echo "shards: job $array (array 0-$((shards - 1))); merge: job $merge; report: $out/report"
