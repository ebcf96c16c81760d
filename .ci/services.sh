#!/usr/bin/env bash
# Install (idempotently, from the distribution's packages) and start PostgreSQL and Redis on
# loopback for the service tests (tests/service). Safe to run again: it only installs what is
# missing and only starts what is not running. Prints the URLs the tests read.
#   CASCALIB_TEST_POSTGRES_URL=postgresql+psycopg://cascalib:cascalib@127.0.0.1:5432/postgres
#   CASCALIB_TEST_REDIS_URL=redis://127.0.0.1:6379
set -euo pipefail

need=()
command -v redis-server >/dev/null 2>&1 || need+=(redis-server)
ls /usr/lib/postgresql/*/bin/pg_ctl >/dev/null 2>&1 || need+=(postgresql)
if [ ${#need[@]} -gt 0 ]; then
    if [ "$(id -u)" -ne 0 ]; then
        echo "services.sh: need root to install ${need[*]}; service tests will skip" >&2
        exit 0
    fi
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq >/dev/null
    apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi

# Redis: loopback only, no persistence (test data).
if ! redis-cli -h 127.0.0.1 -p 6379 ping >/dev/null 2>&1; then
    redis-server --bind 127.0.0.1 --port 6379 --save '' --appendonly no --daemonize yes \
        --logfile /tmp/cascalib-redis.log
    for _ in $(seq 50); do redis-cli -h 127.0.0.1 -p 6379 ping >/dev/null 2>&1 && break; sleep 0.1; done
fi

# PostgreSQL: the distribution's cluster, listening on loopback; a role that may create the
# per-test-session databases.
PGVER=$(ls /usr/lib/postgresql | sort -V | tail -1)
if ! pg_lsclusters -h 2>/dev/null | grep -q "^$PGVER "; then
    pg_createcluster "$PGVER" main >/dev/null
fi
if ! pg_lsclusters -h | awk -v v="$PGVER" '$1==v && $2=="main" {print $4}' | grep -q online; then
    pg_ctlcluster "$PGVER" main start -- -o "-c listen_addresses=127.0.0.1" 2>/dev/null \
        || pg_ctlcluster "$PGVER" main start
fi
for _ in $(seq 100); do
    su postgres -c "pg_isready -q -h 127.0.0.1 -p 5432" && break; sleep 0.1
done
su postgres -c "psql -q -tAc \"SELECT 1 FROM pg_roles WHERE rolname='cascalib'\"" \
    | grep -q 1 \
    || su postgres -c "psql -q -c \"CREATE ROLE cascalib LOGIN CREATEDB PASSWORD 'cascalib'\""
echo "services.sh: PostgreSQL $PGVER and Redis running on 127.0.0.1"
