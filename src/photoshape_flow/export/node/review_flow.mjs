// A person's review session on `photoshape gallery --serve`, in headless Chromium (playwright-core + the
// system Chromium): open the index, open a PhotoShape, turn it in 3D, enlarge a render, grade it with a key,
// reload, then filter the index to the ungraded ones. Prints one JSON report of what the page showed.
// Usage: node review_flow.mjs CONFIG.json
// CONFIG: {"executable": "/usr/bin/chromium", "url": "http://127.0.0.1:8765/", "pair": 3 | null (first row),
//          "key": "1", "label": "good", "viewport": [1280, 900], "screenshots": "/abs/dir" | null}
// Screenshots (with "screenshots"): review-1-turned.png, review-2-enlarged.png, review-3-graded.png,
// review-4-ungraded.png.
import { readFile } from 'node:fs/promises';
import { join } from 'node:path';
import { chromium } from 'playwright-core';

const config = JSON.parse(await readFile(process.argv[2], 'utf8'));
const [width, height] = config.viewport ?? [1280, 900];
const origin = new URL(config.url).origin;
let clock = Date.now();
const browser = await chromium.launch({
  executablePath: config.executable ?? '/usr/bin/chromium',
  headless: true,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
         '--disable-component-update', '--no-first-run', '--enable-unsafe-swiftshader', '--use-angle=swiftshader'],
});
const entry = { page: config.url, console_errors: [], page_errors: [], failed_requests: [], external_requests: [] };
const report = { browser: browser.version(), pages: [entry], steps: {}, seconds: {} };
// seconds per step, to see where a slow run spends them (software WebGL is the usual one)
const lap = (name) => { report.seconds[name] = (Date.now() - clock) / 1000; clock = Date.now(); };
lap('launch');

const ready = (page) => page.waitForFunction(() => document.documentElement.dataset.review === 'ready',
                                             null, { timeout: 30000 });
async function shoot(page, name, locator) {
  if (!config.screenshots) return;
  const path = join(config.screenshots, name);
  if (locator) await locator.screenshot({ path });
  else await page.screenshot({ path });
}
// the <model-viewer> loaded its model and shows it (software WebGL can take a while)
const viewerShown = (page) => page.waitForFunction(() => {
  const v = document.querySelector('model-viewer');
  return v && v.loaded && v.modelIsVisible;
}, null, { timeout: 90000 });
const orbit = (page) => page.evaluate(() => {
  const o = document.querySelector('model-viewer').getCameraOrbit();
  return { theta: o.theta * 180 / Math.PI, phi: o.phi * 180 / Math.PI, radius: o.radius };
});
const visibleRows = (page) => page.evaluate(() => Array.from(
  document.querySelectorAll('#photoshapes tbody tr'), (r) => ({ pair: Number(r.dataset.pair), grade: r.dataset.grade,
                                                               hidden: r.hidden })));

try {
  const context = await browser.newContext({ viewport: { width, height } });
  const page = await context.newPage();
  page.on('console', (msg) => { if (msg.type() === 'error') entry.console_errors.push(msg.text()); });
  page.on('pageerror', (err) => entry.page_errors.push(String(err)));
  page.on('requestfailed', (req) => entry.failed_requests.push(`${req.url()}: ${req.failure()?.errorText}`));
  await page.route('**/*', (route) => {
    const url = route.request().url();
    if (url.startsWith(`${origin}/`) || url.startsWith('data:') || url.startsWith('blob:')) return route.continue();
    entry.external_requests.push(url);
    return route.abort();
  });

  // 1. the index, in review mode
  await page.goto(config.url, { waitUntil: 'load' });
  await ready(page);
  const rows = await visibleRows(page);
  const pair = config.pair ?? rows[0]?.pair;
  report.steps.index = { rows, summary: await page.locator('#review-summary').textContent(), pair };
  lap('index');

  // 2. open the PhotoShape and turn it: auto-rotate off, then drag across the view
  await page.locator(`#photoshapes tbody tr[data-pair="${pair}"] a`).first().click();
  await page.waitForLoadState('load');
  await ready(page);
  lap('pair page');
  await viewerShown(page);
  lap('3d view loaded');
  await page.evaluate(() => { const v = document.querySelector('model-viewer'); v.autoRotate = false; v.jumpCameraToGoal(); });
  await page.waitForTimeout(300);
  const before = await orbit(page);
  const box = await page.locator('model-viewer').boundingBox();
  const [x, y] = [box.x + box.width / 2, box.y + box.height / 2];
  await page.mouse.move(x, y);
  await page.mouse.down();
  await page.mouse.move(x + box.width / 4, y + 20, { steps: 4 });
  await page.mouse.up();
  let after = await orbit(page);  // the camera eases to where the drag left it: wait until it stops
  for (let last = null; JSON.stringify(last) !== JSON.stringify(after); after = await orbit(page)) {
    last = after;
    await page.waitForTimeout(250);
  }
  report.steps.turn = { before, after };
  await shoot(page, 'review-1-turned.png');
  lap('turn');

  // 3. enlarge the first PhotoShape render
  const render = page.locator('img.zoom[alt^="PhotoShape"]').first();
  const clicked = await render.evaluate((img) => img.src);  // resolved, as the lightbox's img.src is
  await render.click();
  await page.waitForFunction(() => document.getElementById('lightbox').open);
  await page.waitForTimeout(200);
  report.steps.enlarge = await page.evaluate((src) => {
    const box = document.getElementById('lightbox'), big = box.querySelector('img');
    return { open: box.open, width: big.getBoundingClientRect().width, same: big.src === src,
             natural_width: big.naturalWidth };
  }, clicked);
  await shoot(page, 'review-2-enlarged.png');
  lap('enlarge');
  await page.keyboard.press('Escape');

  // 4. grade it with one key; the page shows the grade as soon as the server stored it
  const answer = page.waitForResponse((r) => r.url().endsWith('/api/grade') && r.request().method() === 'POST');
  await page.keyboard.press(config.key);
  const response = await answer;
  await page.waitForFunction((label) => document.getElementById('grade').dataset.grade === label, config.label);
  report.steps.grade = { status: response.status(), body: await response.json(),
                         shown: await page.locator('#grade').textContent(),
                         status_line: await page.locator('#review-status').textContent() };
  await page.locator('#review').scrollIntoViewIfNeeded();
  await shoot(page, 'review-3-graded.png');
  lap('grade');

  // 5. reload: the grade comes back from the database
  await page.reload({ waitUntil: 'load' });
  await ready(page);
  report.steps.reload = { shown: await page.locator('#grade .grade').textContent(),
                          pressed: await page.locator('#review button[aria-pressed="true"]').getAttribute('data-label') };
  lap('reload');

  // 6. the index, then its filter set to the ungraded ones (the URL keeps the choice)
  await page.goto(config.url, { waitUntil: 'load' });
  await ready(page);
  await page.selectOption('#grade-filter', 'ungraded');
  report.steps.ungraded = { rows: await visibleRows(page), count: await page.locator('#count').textContent(),
                            url: page.url() };
  await shoot(page, 'review-4-ungraded.png');
  await page.goto(page.url(), { waitUntil: 'load' });  // opened from the URL the filter left
  await ready(page);
  report.steps.ungraded_url = { rows: await visibleRows(page), filter: await page.inputValue('#grade-filter') };
  lap('ungraded filter');
  await context.close();
} catch (err) {
  report.error = String(err && err.stack || err);
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(report));
