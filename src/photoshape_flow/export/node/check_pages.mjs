// Load static pages in headless Chromium (playwright-core + the system Chromium) and report what a
// person would notice: console errors, page errors, failed or external requests, broken images.
// Usage: node check_pages.mjs CONFIG.json   (prints one JSON report on stdout)
// CONFIG: {"executable": "/usr/bin/chromium", "pages": ["/abs/index.html", ...],
//          "screenshot": "/abs/shot.png" | null, "viewport": [1280, 900],
//          "evaluate": ["js expression run on the first page after load (a promise is awaited)", ...],
//          "screenshot_selector": "css selector: screenshot that element instead of the full page" | null}
import { readFile } from 'node:fs/promises';
import { pathToFileURL } from 'node:url';
import { chromium } from 'playwright-core';

const config = JSON.parse(await readFile(process.argv[2], 'utf8'));
const [width, height] = config.viewport ?? [1280, 900];
const browser = await chromium.launch({
  executablePath: config.executable ?? '/usr/bin/chromium',
  headless: true,
  args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-background-networking',
         '--disable-component-update', '--no-first-run',
         // WebGL (the gallery's 3D view) on the CPU: no GPU in CI, and Chromium no longer falls back silently
         '--enable-unsafe-swiftshader', '--use-angle=swiftshader'],
});
const report = { browser: browser.version(), pages: [] };
try {
  const context = await browser.newContext({ viewport: { width, height } });
  for (const [index, file] of config.pages.entries()) {
    const page = await context.newPage();
    const entry = { page: file, console_errors: [], page_errors: [], failed_requests: [], external_requests: [] };
    page.on('console', (msg) => { if (msg.type() === 'error') entry.console_errors.push(msg.text()); });
    page.on('pageerror', (err) => entry.page_errors.push(String(err)));
    page.on('requestfailed', (req) => entry.failed_requests.push(`${req.url()}: ${req.failure()?.errorText}`));
    await page.route('**/*', (route) => {
      const url = route.request().url();
      if (url.startsWith('file:') || url.startsWith('data:') || url.startsWith('blob:')) return route.continue();
      entry.external_requests.push(url);
      return route.abort();
    });
    const response = await page.goto(pathToFileURL(file).href, { waitUntil: 'load' });
    entry.ok = response === null || response.ok();
    entry.title = await page.title();
    entry.images = await page.evaluate(async () => {
      const images = Array.from(document.images).filter((img) => img.hasAttribute('src'));  // a lightbox's empty img is not broken
      await Promise.all(images.map((img) => (img.complete ? null : img.decode().catch(() => null))));
      return images.map((img) => ({ src: img.getAttribute('src'), natural_width: img.naturalWidth,
                                    natural_height: img.naturalHeight }));
    });
    entry.links = await page.evaluate(() => Array.from(document.querySelectorAll('a[href]'),
                                                         (a) => a.getAttribute('href')));
    if (index === 0) {
      entry.evaluated = [];
      for (const expression of config.evaluate ?? []) entry.evaluated.push(await page.evaluate(expression));
      if (config.screenshot && config.screenshot_selector) {
        await page.locator(config.screenshot_selector).first().screenshot({ path: config.screenshot });
      } else if (config.screenshot) await page.screenshot({ path: config.screenshot, fullPage: true });
    }
    report.pages.push(entry);
    await page.close();
  }
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(report));
