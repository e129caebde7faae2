#!/usr/bin/env bash
# Probe the production shape (PostgreSQL, Redis, `indoorpos serve --workers 3`) with clients
# that cost the server without a good key: 30 MB bodies with a bogus key and with a key
# of the wrong scope, four at a time, then connections sending headers or bodies a byte
# every half second. Uses a Redis of its own (port 6392, nothing on disk) and a PostgreSQL
# database of its own (indoorpos_probe, dropped and made again) on the local server.
# Usage: bash bench/hostile_clients.sh [slow_connections]
set -euo pipefail
cd "$(dirname "$0")/.."
SLOW=${1:-400}
PORT=8392; RPORT=6392; KEY=probe-admin-key
OUT=${OUT:-$(mktemp -d)}
BIN=.venv/bin
URL=http://127.0.0.1:$PORT

redis-server --port "$RPORT" --bind 127.0.0.1 --save "" --appendonly no --daemonize yes \
  --logfile "$OUT/redis.log" --dir "$OUT"
psql -h 127.0.0.1 -U postgres -q -c "DROP DATABASE IF EXISTS indoorpos_probe" \
  -c "CREATE DATABASE indoorpos_probe"
export INDOORPOS_DATABASE_URL=postgresql://postgres@127.0.0.1:5432/indoorpos_probe
export INDOORPOS_REDIS_URL=redis://127.0.0.1:$RPORT/0
export INDOORPOS_ADMIN_KEY=$KEY INDOORPOS_LOG_FORMAT=text
$BIN/indoorpos migrate >/dev/null
$BIN/indoorpos serve --port "$PORT" --workers 3 --no-access-log >"$OUT/api.log" 2>&1 &
API=$!
trap 'kill $API 2>/dev/null; redis-cli -p $RPORT shutdown nosave >/dev/null 2>&1 || true' EXIT
until curl -sf "$URL/readyz" >/dev/null; do sleep 0.2; done
sleep 2  # every worker up

admin=(-H "Authorization: Bearer $KEY" -H "Content-Type: application/json")
site=$(curl -sf "${admin[@]}" -d '{"name": "probe"}' "$URL/v1/sites" | jq -r .id)
building=$(curl -sf "${admin[@]}" -d '{"name": "B"}' "$URL/v1/sites/$site/buildings" | jq -r .id)
floor=$(curl -sf "${admin[@]}" -d '{"level": 0}' "$URL/v1/buildings/$building/floors" | jq -r .id)
viewer=$(curl -sf "${admin[@]}" -d '{"name": "v", "scopes": ["viewer"]}' "$URL/v1/keys" | jq -r .key)
PIDS=()
for pid in $API $(pgrep -P "$API"); do PIDS+=(--pid "$pid"); done

echo "## 4 x 30 MB PUT plan, bogus bearer"
$BIN/python bench/hostile_clients.py bodies --url "$URL" "${PIDS[@]}" \
  --path "/v1/floors/$floor/plan" --bearer x
echo "## 4 x 30 MB PUT plan, viewer key (no maps:write)"
$BIN/python bench/hostile_clients.py bodies --url "$URL" "${PIDS[@]}" \
  --path "/v1/floors/$floor/plan" --bearer "$viewer"
echo "## $SLOW connections, half sending headers and half bodies a byte every 0.5 s"
$BIN/python bench/hostile_clients.py slow --url "$URL" "${PIDS[@]}" --parallel "$SLOW" \
  --bearer "$KEY"
