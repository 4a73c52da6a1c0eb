#!/bin/sh
# Regenerate the bundled demo sites from their simulator specs (deterministic: equal bytes every run).
# Usage: catalog/regenerate.sh   (from anywhere; uses the project's venv if present)
set -eu
here=$(cd "$(dirname "$0")" && pwd)
root=$(dirname "$here")
cli="$root/.venv/bin/cistern-archive"
[ -x "$cli" ] || cli=cistern-archive
for spec in "$here"/specs/*.yaml; do
    "$cli" simulate "$spec" --out "$here" --record-dir sites
done
