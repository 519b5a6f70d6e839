#!/usr/bin/env bash
# Install MathJax 3 (es5 bundle) from the npm registry into book/_build/.mathjax/mathjax, once.
# The book's _config.yml serves it from there, so the built pages typeset math with no network.
set -euo pipefail
cd "$(dirname "$0")/.."
mj=book/_build/.mathjax/mathjax
if [ -f "$mj/tex-chtml.js" ]; then
  exit 0
fi
command -v npm >/dev/null 2>&1 || { echo "install-mathjax: npm is required (Node.js)" >&2; exit 1; }
echo "[book] installing MathJax 3 from the npm registry (offline rendering of the math)"
tmp=$(mktemp -d)
(cd "$tmp" && npm install --silent --no-audit --no-fund mathjax@3 >/dev/null)
mkdir -p "$mj.tmp"
cp -r "$tmp/node_modules/mathjax/es5/." "$mj.tmp/"
mv "$mj.tmp" "$mj"
rm -rf "$tmp"
