#!/bin/sh
# The rba image's entrypoint: run the given command (the image's default is `rba serve`), after joining
# the Ray cluster that RAY_HEAD_ADDRESS names, if it names one (docker-compose.yml sets it for the API
# replicas and the one-shot rba commands; the Ray head and workers start Ray themselves and leave it unset).
#
# Why join: a Ray driver (the process that calls ray.init and submits tasks: `rba serve`, `rba cache`,
# `rba build`) must run on a Ray node. ray.init(address="ray-head:6379") looks for a raylet in its own
# container and, finding none, gives up after a minute ("Failed to connect to Ray cluster"). So this
# container first becomes a node with no CPUs: no task is scheduled here (the workers run them), but the
# driver connects through this node's raylet and its object store receives the results (clip bytes).
# The alternative, Ray Client (RBA_RAY_ADDRESS=ray://ray-head:10001), needs no local node but needs
# `ray[client]` and proxies every object through the head; it is not what compose uses.
set -eu

if [ -n "${RAY_HEAD_ADDRESS:-}" ]; then
    ray start --address="$RAY_HEAD_ADDRESS" --num-cpus=0 --object-store-memory=200000000 --disable-usage-stats
fi
exec "$@"
