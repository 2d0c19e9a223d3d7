#!/usr/bin/env bash
# `make tour`: verify a recorded run of the paper's running example, then show an error.
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
echo

echo "== Live: a monitor handler on real ROS 2 traffic =="
# A private ROS domain, discovery on this machine only.
export ROS_DOMAIN_ID=42 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export EDGERV_TOKEN=demo-token-$RANDOM
port=$(.venv/bin/python -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
rm -f demo-output/live-verdicts.jsonl
$edgerv handler --name demo-edge --monitors examples/speed-limit.yaml \
    --listen "127.0.0.1:$port" --verdict-log demo-output/live-verdicts.jsonl \
    2> demo-output/handler.log &
handler=$!
trap 'kill $handler 2>/dev/null; wait $handler 2>/dev/null' EXIT
for _ in $(seq 100); do grep -q " ready: " demo-output/handler.log && break; sleep 0.2; done
echo "handler started (log: demo-output/handler.log); replaying the trace as ROS messages:"
$edgerv replay --monitors examples/speed-limit.yaml examples/speed-limit.jsonl --interval 0.01
sleep 1
echo "verdicts the handler reported (demo-output/live-verdicts.jsonl):"
cat demo-output/live-verdicts.jsonl
echo "GET /v1/monitors (with the bearer token):"
curl -s -H "Authorization: Bearer $EDGERV_TOKEN" "http://127.0.0.1:$port/v1/monitors" \
    | .venv/bin/python -c 'import json, sys
for m in json.load(sys.stdin)["monitors"]:
    print("  %-14s %-9s step %d  verdicts %s" % (m["name"], m["state"], m["step"], m["verdicts"]))'
echo "without it: HTTP $(curl -s -o /dev/null -w '%{http_code}' "http://127.0.0.1:$port/v1/monitors")"
kill -TERM $handler
wait $handler
echo "handler stopped on SIGTERM with exit code $?"
trap - EXIT
exit 0
