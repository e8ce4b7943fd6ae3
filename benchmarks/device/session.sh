#!/bin/bash
# Issue 18's checks on a lent 16-core device machine, in one call of at most ~590 s
# (the device tool's `run` with carry [".devsite"] and timeout_s 590; .devsite/ from
# pack.sh): run.sh's set-up (about 120 s there), the 10,000-pair batch on 1 and 2 nodes
# (separate clusters and paired, 9 requests each: about 210 s), then, with the time left,
# the Serve measures on 1 and 2 replicas. Each step runs under a timeout that leaves the
# next its time; its log and JSON come back from $OUT, tagged "batch" and "serve".
S=$SECONDS
TAG=batch timeout 380 bash benchmarks/device/run.sh --only batch --repeats 9
echo "batch ended at $((SECONDS - S)) s"
left=$((575 - (SECONDS - S)))
if [ $left -gt 120 ]; then
    TAG=serve REPLICAS=1,2 SECS=8 timeout $left bash benchmarks/device/run.sh --only serve --requests 200
    echo "serve ended at $((SECONDS - S)) s"
fi
