#!/usr/bin/env bash
# Fault run: the session store (Redis) restarts WITHOUT its data while simulated phones
# walk. Uses a Redis of its own (port 6391, nothing on disk) and a PostgreSQL database of
# its own (indoorpos_faults, dropped and made again) on the local server.
# Usage: bash bench/redis_restart.sh [users] [duration_s] [restart_at_s]
set -euo pipefail
cd "$(dirname "$0")/.."
USERS=${1:-20}; DURATION=${2:-60}; RESTART_AT=${3:-20}
PORT=8391; RPORT=6391; KEY=faults-admin-key
OUT=${OUT:-$(mktemp -d)}
BIN=.venv/bin

redis() { redis-server --port "$RPORT" --bind 127.0.0.1 --save "" --appendonly no \
  --daemonize yes --logfile "$OUT/redis.log" --dir "$OUT"; }
redis
psql -h 127.0.0.1 -U postgres -q -c "DROP DATABASE IF EXISTS indoorpos_faults" \
  -c "CREATE DATABASE indoorpos_faults"
export INDOORPOS_DATABASE_URL=postgresql://postgres@127.0.0.1:5432/indoorpos_faults
export INDOORPOS_REDIS_URL=redis://127.0.0.1:$RPORT/0
export INDOORPOS_ADMIN_KEY=$KEY INDOORPOS_RATE_LIMITS=false INDOORPOS_LOG_FORMAT=text
$BIN/indoorpos migrate >/dev/null
$BIN/indoorpos serve --port "$PORT" --no-access-log >"$OUT/api.log" 2>&1 &
API=$!
trap 'kill $API 2>/dev/null; redis-cli -p $RPORT shutdown nosave >/dev/null 2>&1 || true' EXIT
until curl -sf "http://127.0.0.1:$PORT/readyz" >/dev/null; do sleep 0.2; done

$BIN/indoorpos simulate --url "http://127.0.0.1:$PORT" --admin-key "$KEY" --users "$USERS" \
  --duration "$DURATION" --engine pf_magnetic --json "$OUT/simulate.json" >"$OUT/simulate.log" 2>&1 &
SIM=$!
sleep "$RESTART_AT"
redis-cli -p "$RPORT" dbsize | sed 's/^/redis keys before the restart: /'
redis-cli -p "$RPORT" shutdown nosave >/dev/null || true
sleep 1
redis
until redis-cli -p "$RPORT" ping >/dev/null 2>&1; do sleep 0.1; done
echo "redis restarted empty at ${RESTART_AT} s"
wait "$SIM" || true
python3 - "$OUT/simulate.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
keys = ("users", "sessions", "batches", "steps", "errors", "p50_ms", "p99_ms", "mean_error_m")
print({k: s.get(k) for k in keys})
import re
statuses = {}
for m in s.get("error_messages", []):
    found = re.search(r": (\d{3}) ", m)
    code = found.group(1) if found else "other"
    statuses[code] = statuses.get(code, 0) + 1
print("errors by status (of the first messages kept):", statuses)
PY
echo "sessions rebuilt (api log): $(grep -c 'rebuilt: the session store had lost it' "$OUT/api.log" || true)"
echo "logs in $OUT"
