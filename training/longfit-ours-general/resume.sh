#!/usr/bin/env bash
# Resume issue 24's long fit from the state committed here (a session's machine does not keep
# /work/fit between sessions). Restores /work/fit, the code snapshot it runs (commit 62efc22,
# so that the whole fit runs one code), and starts it in the background with --resume.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../.." && pwd)"
[ -x "$repo/.venv/bin/python" ] || "$repo/scripts/setup"
mkdir -p /work/fit/general
if [ ! -f /work/fit/general/last.pt ]; then
    cp "$here/state/last.pt" "$here/state/last.json" "$here/state/recipe.yaml" /work/fit/general/
    cp "$here/state/mlflow.db" /work/fit/
    mkdir -p /work/fit/mlartifacts  # the run's artifact folder (its earlier images are not kept)
    cat "$here/state/fit.log" > /work/fit/fit.log
fi
git -C "$repo" worktree prune
[ -d /work/fitsnap ] || git -C "$repo" worktree add -q --detach /work/fitsnap 62efc22
cp "$here/run.sh" /work/fit/run.sh
cd /work/fit && setsid nohup ./run.sh --resume >> fit.log 2>&1 < /dev/null &
echo "resumed; follow /work/fit/fit.log"
