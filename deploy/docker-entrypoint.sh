#!/bin/sh
# The image's entrypoint: no arguments, or arguments that start with "-", run brenierd on
# 0.0.0.0:50051 with its data in /data (those arguments are further brenierd flags); anything
# else (brenier-compute ..., brenier ..., sh -c ...) runs as it stands.
set -e
if [ "$#" -eq 0 ] || [ "${1#-}" != "$1" ]; then
  exec /usr/local/bin/brenierd --listen 0.0.0.0:50051 --data /data "$@"
fi
exec "$@"
