#!/usr/bin/env bash
# `make demo`: verify a recorded run of the paper's running example, then show an error.
set -uo pipefail
cd "$(dirname "$0")/.."
edgerv=.venv/bin/edgerv
mkdir -p demo-output

echo "== The monitors (examples/speed-limit.yaml) =="
grep -E '^(  name|  assertion| +[a-z_]+: \{topic)' examples/speed-limit.yaml
echo
echo "== edgerv check examples/speed-limit.yaml examples/speed-limit.jsonl =="
$edgerv check examples/speed-limit.yaml examples/speed-limit.jsonl
echo "(exit code $?: 1 means a monitor was violated)"
$edgerv check examples/speed-limit.yaml examples/speed-limit.jsonl --json > demo-output/verdicts.json
echo "JSON verdicts written to demo-output/verdicts.json:"
cat demo-output/verdicts.json
echo
echo "== A typo in an assertion is reported where it is (exit code 2) =="
sed 's/speed < limit/sped < limit/' examples/speed-limit.yaml > demo-output/typo.yaml
$edgerv check demo-output/typo.yaml examples/speed-limit.jsonl
echo "(exit code $?)"
exit 0
