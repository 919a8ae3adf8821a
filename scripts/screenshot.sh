#!/usr/bin/env bash
# Screenshot of the demo recording in the real Rerun web viewer, for docs/img/demo.png.
#
# Usage: scripts/screenshot.sh [FILE.rrd] [OUT.png]   (defaults: out/demo/report.rrd from `objloc demo`, docs/img/demo.png)
# Installs what it needs: Debian `chromium` (apt-get) when /usr/bin/chromium is missing,
# `playwright-core` (npm) into target/screenshot/, and uses the pinned rerun-sdk of the test
# venv (target/pyenv, created by `cargo test --release --test it viz` or tests/it/interop.rs).
# Serves FILE.rrd with `rerun --web-viewer` (the viewer of the same version as the crate),
# opens it in headless Chromium with software GL (SwiftShader), waits for the viewer to
# render, and saves the page. Not part of CI: it needs network for the first install.
set -euo pipefail
cd "$(dirname "$0")/.."
RRD="${1:-out/demo/report.rrd}"
OUT="${2:-docs/img/demo.png}"
WAIT_MS="${WAIT_MS:-45000}"  # the software rasterizer needs ~40 s to load and lay out
PYENV="${OBJLOC_PYENV:-target/pyenv}"
[ -f "$RRD" ] || { echo "error: $RRD not found (run objloc demo first)" >&2; exit 1; }
[ -x "$PYENV/bin/rerun" ] || { echo "error: $PYENV/bin/rerun missing (run cargo test --release --test it viz once)" >&2; exit 1; }
if [ ! -x /usr/bin/chromium ]; then
  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
fi
mkdir -p target/screenshot
if [ ! -d target/screenshot/node_modules/playwright-core ]; then
  (cd target/screenshot && npm init -y >/dev/null && npm install --silent playwright-core@1 >/dev/null)
fi
mkdir -p "$(dirname "$OUT")"
PORT_WEB="${PORT_WEB:-9190}"
PORT_GRPC="${PORT_GRPC:-9976}"
# In its own process group: the Python entry point starts the viewer binary as a child, and
# both must go when the script ends (a leftover server would also answer the next run).
setsid "$PYENV/bin/rerun" --web-viewer --web-viewer-port "$PORT_WEB" --port "$PORT_GRPC" "$RRD" >target/screenshot/rerun.log 2>&1 &
RERUN_PID=$!
trap 'kill -- -$RERUN_PID 2>/dev/null || true' EXIT
for _ in $(seq 1 60); do
  curl -s -o /dev/null "http://127.0.0.1:$PORT_WEB/" && break
  sleep 0.5
done
URL="http://127.0.0.1:$PORT_WEB/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$PORT_GRPC%2Fproxy"
NODE_PATH="$PWD/target/screenshot/node_modules" node - "$URL" "$OUT" "$WAIT_MS" <<'JS'
const { chromium } = require('playwright-core');
const [url, out, waitMs] = process.argv.slice(2);
(async () => {
  const browser = await chromium.launch({
    executablePath: '/usr/bin/chromium',
    args: ['--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--headless',
           '--no-sandbox', '--disable-background-networking', '--disable-component-update',
           '--disable-sync', '--no-first-run'],
  });
  const page = await browser.newPage({ viewport: { width: 1600, height: 1000 } });
  page.on('console', (m) => { if (m.type() === 'error') console.error('viewer:', m.text()); });
  await page.goto(url);
  await page.waitForTimeout(Number(waitMs));
  await page.screenshot({ path: out });
  await browser.close();
  console.log(`saved ${out}`);
})().catch((e) => { console.error(e); process.exit(1); });
JS
