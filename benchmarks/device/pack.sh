#!/bin/bash
# Packs what benchmarks/cluster.py needs on a machine that has Python 3.12, numpy, numba and
# the rest of a scientific image but no network (the 16-core device machine of BENCHMARKS.md
# "on 16 cores"): the cluster's Python 3.12 wheels installed into site/ (Ray without its
# Java jars, RLlib, Data, Tune, Train and LLM packages; moto with the S3 parts alone; the
# image's own packages left out), PostgreSQL 16.2's server from the pgserver wheel in pg/,
# and grpcio-reflection matching that image's grpcio 1.84. Writes .devsite/ (git-ignored
# by .gitignore), which travels with the working tree; run.sh runs there.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
WORK=$(mktemp -d)
PLATFORMS="--platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform manylinux_2_34_x86_64"
PY312="--only-binary=:all: --python-version 3.12 --implementation cp $PLATFORMS"
cd "$WORK"
python3 -m pip download -q $PY312 -d wheels "ray[serve]==2.60.0" fastapi==0.165.0 starlette==1.10.0 \
    uvicorn==0.54.0 pydantic==2.14.4 pydantic-settings==2.16.3 python-multipart==0.0.34 \
    "psycopg[binary,pool]==3.3.9" psycopg-pool==3.3.3 trimesh==5.2.0 "moto[server]==5.2.5" boto3==1.44.8
python3 -m pip download -q --no-deps $PY312 -d pgwheel pgserver==0.1.4
python3 -m pip download -q --no-deps --only-binary=:all: -d "$ROOT/.devsite" grpcio-reflection==1.84.0
# on the image already (or not needed: runtime environments, profiling, docker)
SKIP="aiohappyeyeballs aiohttp aiosignal annotated_doc anyio attrs certifi charset_normalizer click filelock frozenlist grpcio h11 idna jinja2 markupsafe mpmath msgpack multidict networkx numpy packaging prometheus_client propcache protobuf pyyaml requests six sympy typing_extensions urllib3 uvloop yarl wrapt werkzeug python_dateutil pyparsing regex virtualenv distlib platformdirs python_discovery py_spy docker cfn_lint aws_xray_sdk grpcio_reflection"
files=()
for f in wheels/*.whl; do
    name=$(basename "$f" | sed -E 's/-[0-9].*//')
    [[ " $SKIP " == *" $name "* ]] || files+=("$f")
done
python3 -m pip install -q --no-deps --no-compile --target site $PY312 "${files[@]}"
rm -rf site/ray/{jars,rllib,data,tune,train,llm} site/ray/dashboard/client/build/static/js/*.map \
    site/ray/dashboard/client/build/speedscope*
(cd site/moto && for d in */; do case ${d%/} in core|s3|s3bucket_path|moto_api|moto_server|utilities|cloudwatch|events|iam|sts) ;; *) rm -rf "$d";; esac; done)
(cd site/botocore/data && for d in */; do case ${d%/} in s3|s3control|sts|iam) ;; *) rm -rf "$d";; esac; done)
find site -name __pycache__ -prune -exec rm -rf {} +
mkdir pg && (cd pgwheel && python3 -m zipfile -e pgserver-*.whl x) && cp -r pgwheel/x/pgserver/pginstall/{bin,lib,share} pg/
chmod -R a+rX pg
mkdir -p "$ROOT/.devsite"
tar cf - site pg | xz -T0 -6 > "$ROOT/.devsite/site.tar.xz"
cp "$ROOT/benchmarks/device/run.sh" "$ROOT/.devsite/run.sh"
ls -la "$ROOT/.devsite"
rm -rf "$WORK"
