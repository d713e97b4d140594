#!/usr/bin/env bash
# Every function of core/, server/, client/ and tools/ within LIMIT lines (default 120),
# measured from its signature to its closing brace by Universal Ctags (lambdas count toward
# the function they are written in). Prints the offenders, longest first; exits 1 if any.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
limit="${1:-120}"
command -v ctags >/dev/null || { echo "check-function-sizes: ctags (universal-ctags) is not installed" >&2; exit 2; }
cd "$root"
ctags -R --languages=C++ --c++-kinds=f --fields=+ne --extras=-F -o - core server client tools |
  awk -F'\t' -v limit="$limit" '
    $1 !~ /^__anon/ {
      line = ""; end = ""
      for (i = 4; i <= NF; i++) {
        if ($i ~ /^line:/) line = substr($i, 6)
        if ($i ~ /^end:/) end = substr($i, 5)
      }
      if (end != "" && end - line + 1 > limit) { print end - line + 1 " lines: " $2 ":" line " " $1; bad = 1 }
    }
    END { exit bad }' | sort -rn || { echo "functions above $limit lines (split them where a reader would)" >&2; exit 1; }
