#!/usr/bin/env bash
# Runs every command that README.md quotes in a ```sh block, literally, from the repository root,
# so that a command the README shows cannot rot. `.ci/run` calls it after the tests.
#
# - A command is one line of a ```sh block, or several joined by a trailing backslash; blank
#   lines and lines that start with `#` are skipped (a `# ...` comment after a command is bash's).
# - Each runs in its own `bash -e -o pipefail -c` (a `cd` or `export` does not carry over), with
#   the workspace's binaries on PATH: `dc` in the README is `<cargo target dir>/debug/dc`.
# - The two set-up commands are skipped, by exact text: `.ci/run` already runs them (the tests
#   literally, the main job in a short form). If either is missing from README.md this script
#   fails, so that README and .ci/run are changed together.
# - Each command gets DC_README_TIMEOUT seconds (default 300); the first failure stops the script
#   and names the command.
#
# - With arguments, the same for those documents instead (`check-readme.sh docs/python.md ...`),
#   in order: a user follows README.md, then the pages it links. A command whose line ends with the
#   comment ending `not run by CI` is shown for people only (one that runs for minutes, or names a
#   file of the reader's own); a test covers what it shows.
#
# Needs the binaries built (`cargo build --workspace --bins`) and the Python packages of
# python/requirements.txt (as .ci/run installs them).
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "$#" -gt 0 ]; then
  for doc in "$@"; do
    DC_CHECK_DOC="$doc" bash "$0"
  done
  exit 0
fi
readme="${DC_CHECK_DOC:-README.md}"
limit="${DC_README_TIMEOUT:-300}"
setup_commands=(
  'cargo build --workspace --bins && cargo run --bin dc -- eval'
  'cargo build --workspace --bins && cargo test --workspace'
)

# The commands of the ```sh blocks, one per line (continuation lines joined).
extract() {
  awk '
    /^```sh[[:space:]]*$/ { inside = 1; next }
    /^```/                { if (inside && pending != "") { print pending; pending = "" } inside = 0; next }
    inside {
      line = $0
      if (pending == "" && (line ~ /^[[:space:]]*$/ || line ~ /^[[:space:]]*#/)) next
      if (line ~ /\\[[:space:]]*$/) { sub(/\\[[:space:]]*$/, "", line); pending = pending line; next }
      print pending line; pending = ""
    }
  ' "$readme"
}

mapfile -t commands < <(extract)
if [ "$readme" != README.md ]; then
  setup_commands=()
fi
for setup in "${setup_commands[@]}"; do
  found=0
  for c in "${commands[@]}"; do [ "$c" = "$setup" ] && found=1; done
  if [ "$found" = 0 ]; then
    echo "check-readme: the set-up command \`$setup\` is not in a \`\`\`sh block of $readme;" >&2
    echo "check-readme: .ci/run runs it, so change .ci/run and this script with the README" >&2
    exit 1
  fi
done

target_dir="${CARGO_TARGET_DIR:-$(cargo metadata --format-version 1 --no-deps \
  | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')}"
if [ ! -x "$target_dir/debug/dc" ]; then
  echo "check-readme: $target_dir/debug/dc not found; build first: cargo build --workspace --bins" >&2
  exit 1
fi
export PATH="$target_dir/debug:$PATH"

ran=0
skipped=0
for c in "${commands[@]}"; do
  is_setup=0
  for setup in "${setup_commands[@]}"; do [ "$c" = "$setup" ] && is_setup=1; done
  if [ "$is_setup" = 1 ]; then
    echo "check-readme: skip (run by .ci/run): $c"
    skipped=$((skipped + 1))
    continue
  fi
  if [[ "$c" =~ \#.*not\ run\ by\ CI[[:space:]]*$ ]]; then
    echo "check-readme: skip (for people only): $c"
    skipped=$((skipped + 1))
    continue
  fi
  echo "check-readme: \$ $c"
  start=$SECONDS
  status=0
  timeout --kill-after=10 "$limit" bash -e -o pipefail -c "$c" || status=$?
  if [ "$status" != 0 ]; then
    if [ "$status" = 124 ] || [ "$status" = 137 ]; then
      echo "check-readme: FAILED (timed out after ${limit} s): $c" >&2
    else
      echo "check-readme: FAILED (exit status $status): $c" >&2
    fi
    exit 1
  fi
  echo "check-readme: ok in $((SECONDS - start)) s"
  ran=$((ran + 1))
done
echo "check-readme: all $ran commands of $readme ran ($skipped left to .ci/run or for people only)"
