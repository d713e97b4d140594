#!/usr/bin/env bash
# The Debian packages that hold the shared libraries the given programs load (ldd, then
# dpkg -S on each library's real path): what the image's runtime stage installs, so that it
# carries exactly the programs' libraries and no compiler or -dev package.
#   deploy/runtime-packages.sh /stage/usr/local/bin/* > runtime-packages.txt
set -euo pipefail
for program in "$@"; do
  ldd "$program" | awk '/=> \// {print $3} /^\t\/.* \(0x/ {print $1}'
done | sort -u | while read -r lib; do
  real="$(readlink -f "$lib")"
  for path in "$real" "${real#/usr}" "/usr$real" "$lib"; do
    if pkg="$(dpkg -S "$path" 2>/dev/null)"; then
      echo "${pkg%%:*}"
      break
    fi
  done
done | sort -u
