// The studio in a real browser (Debian's chromium driven by playwright-core), against a
// running raytile server. Run by tests/it/studio.rs, which starts the server and makes
// the fixtures; by hand:
//
//   node web/test/studio.test.mjs URL FIXTURES SHOTS
//
// URL is the server, FIXTURES a folder holding `flipped.png` (the lecture's reference
// flipped vertically) and `big.json` (a scene that renders for many seconds), SHOTS the
// folder for a screenshot of each step. Each case prints `ok` or `not ok` with why, and
// the last line counts them.
import { chromium } from "playwright-core";
import { mkdirSync, readFileSync } from "node:fs";
import { deflateSync } from "node:zlib";
import { pngStream } from "../src/png.js";

const [url, fixtures, shots] = process.argv.slice(2);
if (!url || !fixtures || !shots) {
  console.error("usage: node studio.test.mjs URL FIXTURES SHOTS");
  process.exit(2);
}
mkdirSync(shots, { recursive: true });

const browser = await chromium.launch({
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  headless: true,
  args: ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update", "--no-first-run"],
});
const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
const errors = [];
page.on("pageerror", (e) => errors.push(e.message));
// A refused request is logged by the browser itself; the page shows its problem.
page.on("console", (m) => m.type() === "error" && !/^Failed to load resource/.test(m.text()) && errors.push(m.text()));
const byId = (id) => page.getByTestId(id);

let passed = 0;
let failed = 0;
async function step(name, body) {
  try {
    await body();
    passed++;
    console.log(`ok - ${name}`);
  } catch (e) {
    failed++;
    console.log(`not ok - ${name}\n  ${String(e.stack ?? e).split("\n").join("\n  ")}`);
  }
  await page.screenshot({ path: `${shots}/${name.replace(/\W+/g, "-")}.png` }).catch(() => {});
}
function check(cond, what) {
  if (!cond) throw new Error(what);
}
const timeout = 30_000;

async function rays() {
  const text = await (await fetch(`${url}/metrics`)).text();
  return Number(text.match(/^raytile_rays_traced_total (\S+)$/m)[1]);
}

async function setScene(text) {
  await page.evaluate((t) => {
    const v = window.studio.view;
    v.dispatch({ changes: { from: 0, to: v.state.doc.length, insert: t } });
  }, text);
}

/** A PNG of `rgb` (w × h × 3 bytes), row y filtered with filter type y mod 5, its
 * IDAT split in two around nothing in particular, a tEXt chunk before it; 16-bit when
 * asked (then only the header matters). CRCs are left zero: the decoder skips them. */
function encodePng(w, h, rgb, depth = 8) {
  const stride = 3 * w;
  const raw = new Uint8Array(h * (stride + 1));
  const paeth = (a, b, c) => {
    const p = a + b - c, pa = Math.abs(p - a), pb = Math.abs(p - b), pc = Math.abs(p - c);
    return pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
  };
  for (let y = 0; y < h; y++) {
    const f = y % 5;
    raw[y * (stride + 1)] = f;
    for (let i = 0; i < stride; i++) {
      const x = rgb[y * stride + i];
      const a = i >= 3 ? rgb[y * stride + i - 3] : 0;
      const b = y ? rgb[(y - 1) * stride + i] : 0;
      const c = y && i >= 3 ? rgb[(y - 1) * stride + i - 3] : 0;
      const pred = [0, a, b, (a + b) >> 1, paeth(a, b, c)][f];
      raw[y * (stride + 1) + 1 + i] = (x - pred) & 255;
    }
  }
  const z = deflateSync(raw);
  const chunk = (type, data) => {
    const out = Buffer.alloc(12 + data.length);
    out.writeUInt32BE(data.length, 0);
    out.write(type, 4, "latin1");
    Buffer.from(data).copy(out, 8);
    return out;
  };
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(w, 0);
  ihdr.writeUInt32BE(h, 4);
  ihdr[8] = depth;
  ihdr[9] = 2;
  const cut = Math.floor(z.length / 3);
  return Buffer.concat([Buffer.from([137, 80, 78, 71, 13, 10, 26, 10]), chunk("IHDR", ihdr),
    chunk("tEXt", Buffer.from("Software\0test")), chunk("IDAT", z.subarray(0, cut)),
    chunk("IDAT", z.subarray(cut)), chunk("IEND", Buffer.alloc(0))]);
}

await step("the streaming PNG decoder reads every row filter, fed in pieces", async () => {
  const [w, h] = [7, 11];
  let seed = 7;
  const rgb = Uint8Array.from({ length: 3 * w * h }, () => (seed = (seed * 1103515245 + 12345) % 2147483648) >> 16 & 255);
  const png = encodePng(w, h, rgb);
  const got = new Uint8Array(4 * w * h);
  let header = null;
  const bands = [];
  const d = pngStream({
    onHeader: (a, b) => { header = [a, b]; },
    onRows: (y, n, rgba) => { bands.push([y, n]); got.set(rgba, 4 * w * y); },
  });
  for (let at = 0, k = 0; at < png.length; k++) {
    const n = 1 + (k * 5) % 13;
    check(d.push(png.subarray(at, at + n)), `refused at byte ${at}`);
    at += n;
    // Let the inflater run between pieces, so rows come in several bands.
    await new Promise((r) => setTimeout(r, 0));
  }
  check(await d.end(), "not every row was drawn");
  check(header?.join() === "7,11", `the header says ${header}`);
  for (let i = 0; i < w * h; i++) {
    const want = [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2], 255].join();
    const have = [...got.subarray(4 * i, 4 * i + 4)].join();
    check(have === want, `pixel ${i % w}, ${Math.floor(i / w)} is ${have}, not ${want}`);
  }
  check(bands.every(([y], i) => i === 0 || y === bands[i - 1][0] + bands[i - 1][1]), "bands out of order");
  // A PNG it does not draw (16 bits a channel) is refused, for the page to show whole.
  const deep = pngStream({ onHeader: () => {}, onRows: () => {} });
  check(!deep.push(encodePng(2, 2, new Uint8Array(12), 16)), "a 16-bit PNG is accepted");
  check(!pngStream({ onHeader: () => {}, onRows: () => {} }).push(Buffer.from("GIF89a....")), "a GIF is accepted");
});

await step("load the page, pick the lecture scene, render it", async () => {
  await page.goto(url);
  await byId("example-picker").selectOption({ label: /^lecture/ }).catch(async () => {
    const value = await page.$eval("[data-testid=example-picker]", (s) =>
      [...s.options].find((o) => o.textContent.startsWith("lecture")).value);
    await byId("example-picker").selectOption(value);
  });
  await page.waitForFunction(() => window.studio.view.state.doc.toString().includes('"ball"'), null, { timeout });
  await byId("render-button").click();
  await page.waitForFunction(() => {
    const img = document.querySelector("[data-testid=render-image]");
    return img.complete && img.naturalWidth === 5 && /rendered/.test(document.querySelector("[data-testid=render-status]").textContent);
  }, null, { timeout });
  const box = await byId("render-image").boundingBox();
  check(box.width >= 100, `the 5 × 5 image is zoomed to ${box.width} px`);
  const rendering = await page.evaluate(() => getComputedStyle(document.querySelector("[data-testid=render-image]")).imageRendering);
  check(rendering === "pixelated", `image-rendering is ${rendering}`);
  const statusText = await byId("render-status").textContent();
  check(/rays/.test(statusText), `the status says ${statusText}`);
});

await step("click pixel (2, 2) and read lambda = 2 in the trace panel", async () => {
  const box = await byId("render-image").boundingBox();
  await page.mouse.click(box.x + (2.5 / 5) * box.width, box.y + (2.5 / 5) * box.height);
  await page.waitForFunction(() => /λ = 2\b/.test(document.querySelector("[data-testid=trace-panel]").textContent), null, { timeout });
  const text = await byId("trace-panel").textContent();
  check(text.startsWith("Pixel (2, 2)"), `the trace names another pixel: ${text.slice(0, 40)}`);
  // The JSON ray tree beside it, folded: opening a branch shows its fields.
  const top = page.locator("#trace-tree > details > summary");
  await top.waitFor({ timeout });
  check(/ray tree/.test(await top.textContent()), "the ray tree is offered");
  check(await page.locator("#trace-tree .leaf, #trace-tree details details").count() > 0, "the tree has branches");
});

/** Canvas pixels of the overlay in column `x` between rows `y0` and `y1`, as RGBA. */
async function column(x, y0, y1) {
  return page.$eval("#grid", (c, [x, y0, y1]) => {
    const d = c.getContext("2d").getImageData(x - 1, y0, 3, y1 - y0).data;
    const out = [];
    for (let i = 0; i < d.length; i += 4) out.push([d[i], d[i + 1], d[i + 2], d[i + 3]]);
    return out;
  }, [x, y0, y1]);
}

await step("the pixel's rays are drawn over the image", async () => {
  // Pixel (2, 2)'s primary ray is seen end on, and its shadow ray grazes the ball it
  // leaves: blocked at once, a red cross on the pixel's centre.
  await page.locator("#ray-legend", { hasText: "shadow" }).waitFor({ timeout });
  check(/primary/.test(await page.locator("#ray-legend").textContent()), "the legend names the primary ray");
  const z = await page.evaluate(() => document.querySelector("#grid").width / 5);
  const red = await column(Math.round(2.5 * z) + 3, Math.round(2.5 * z) - 5, Math.round(2.5 * z) + 5);
  check(red.some((px) => px[0] > 200 && px[1] < 120 && px[2] < 120), "no cross where the shadow ray is blocked");
  // From (3, 2) the shadow ray reaches the light at (0, −4, 0): on screen, straight up.
  const box = await byId("render-image").boundingBox();
  await page.mouse.click(box.x + (3.5 / 5) * box.width, box.y + (2.5 / 5) * box.height);
  await page.waitForFunction(() => document.querySelector("[data-testid=trace-panel]").textContent.startsWith("Pixel (3, 2)"), null, { timeout });
  await page.waitForFunction(() => window.studio.selected()?.[0] === 3 && document.querySelector("#ray-legend").textContent.includes("shadow"), null, { timeout });
  const light = (px) => px[3] > 200 && px[0] > 200 && px[1] > 200 && px[2] > 200;
  const up = await column(Math.round(3.5 * z), Math.round(0.2 * z), Math.round(2.2 * z));
  check(up.filter(light).length > up.length / 8, `the shadow ray is not drawn above (3, 2): ${up.filter(light).length} of ${up.length}`);
  const down = await column(Math.round(3.5 * z), Math.round(3.2 * z), Math.round(4.8 * z));
  check(!down.some(light), "a ray is drawn below the pixel");
  await page.screenshot({ path: `${shots}/rays-over-the-image.png` });
  await page.locator("#show-rays").uncheck();
  const hidden = await column(Math.round(3.5 * z), Math.round(0.2 * z), Math.round(2.2 * z));
  check(!hidden.some(light), "the rays stay when turned off");
  await page.locator("#show-rays").check();
});

await step("a typo in the editor shows the problem at its pointer", async () => {
  const doc = await page.evaluate(() => window.studio.view.state.doc.toString());
  const at = doc.indexOf("focal_length");
  check(at > 0, "the lecture scene has a focal length");
  await page.evaluate((from) => window.studio.view.dispatch({ selection: { anchor: from, head: from + "focal_length".length } }), at);
  await page.locator(".cm-content").focus();
  await page.keyboard.type("focal_lenght");
  const item = page.locator("#problems li", { hasText: "/camera/focal_lenght" });
  await item.first().waitFor({ timeout });
  const mark = page.locator(".cm-lintRange-error");
  await mark.first().waitFor({ timeout });
  // The marked range is the misspelt field's value: the line that holds it.
  const line = await page.locator(".cm-line", { has: mark.first() }).first().textContent();
  check(line.includes("focal_lenght"), `the mark is on "${line}"`);
  await page.keyboard.press("Control+z");
  await page.waitForFunction(() => document.querySelectorAll("#problems li").length === 0, null, { timeout });
});

await step("a PNG flipped vertically fails, with its difference image", async () => {
  await byId("grade-input").setInputFiles(`${fixtures}/flipped.png`);
  await page.locator("[data-testid=grade-result] .verdict").waitFor({ timeout });
  const verdict = await page.locator("[data-testid=grade-result] .verdict").textContent();
  check(verdict === "FAIL", `the verdict is ${verdict}`);
  const text = await byId("grade-result").textContent();
  check(/upside down/i.test(text), `the diagnosis names the flip: ${text}`);
  await page.waitForFunction(() => {
    const img = document.querySelector("[data-testid=diff-image]");
    return !img.hidden && img.complete && img.naturalWidth === 5;
  }, null, { timeout });
  // The reference on screen and the submission, under one slider.
  await page.locator("#wipe").waitFor({ state: "visible", timeout });
  await page.locator("#wipe-at").fill("20");
  const clip = await page.$eval("#wipe-sub", (i) => i.style.clipPath);
  check(clip === "inset(0px 0px 0px 20%)" || clip === "inset(0 0 0 20%)", `the slider clips at ${clip}`);
});

await step("a worst pixel's entry shows its trace", async () => {
  const first = page.locator("[data-testid=grade-result] ol button").first();
  const label = await first.textContent();
  const [, u, v] = label.match(/\((\d+), (\d+)\)/).map(Number);
  await first.click();
  await page.waitForFunction((p) => document.querySelector("[data-testid=trace-panel]").textContent.startsWith(p), `Pixel (${u}, ${v})`, { timeout });
  await page.locator("#ray-legend", { hasText: "primary" }).waitFor({ timeout });
  const selected = await page.evaluate(() => window.studio.selected());
  check(selected?.[0] === u && selected?.[1] === v, `the selected pixel is ${selected}`);
  check(await first.getAttribute("aria-pressed") === "true", "the entry does not show it is selected");
});

/** The RGBA of canvas `sel` at pixel (x, y). */
async function pixel(sel, x, y) {
  return page.$eval(sel, (c, [x, y]) => [...c.getContext("2d").getImageData(x, y, 1, 1).data], [x, y]);
}

await step("hit data from NPY: objects, depth and normals", async () => {
  const accepts = [];
  page.on("request", (r) => r.url().endsWith("/v1/hits") && accepts.push(r.headers().accept));
  await page.locator("#hits-mode").selectOption("objects");
  await byId("hits-view").waitFor({ state: "visible", timeout });
  await page.locator("#legend", { hasText: "ball" }).waitFor({ timeout });
  check(accepts.length === 1 && accepts[0] === "application/x-npy", `hit data asked for ${accepts}`);
  // The ball is object 0, the palette's first colour; a miss stays transparent.
  let c = await pixel("#hits-canvas", 2, 2);
  check(c.join() === "78,121,167,255", `objects at (2, 2): ${c}`);
  c = await pixel("#hits-canvas", 0, 0);
  check(c[3] === 0, `a miss at (0, 0) is drawn: ${c}`);
  await byId("hits-view").scrollIntoViewIfNeeded();
  const box = await byId("hits-view").boundingBox();
  await page.mouse.move(box.x + (1.5 / 5) * box.width, box.y + (1.5 / 5) * box.height);
  await page.mouse.move(box.x + (2.5 / 5) * box.width, box.y + (2.5 / 5) * box.height);
  await page.locator("#hover", { hasText: "(u, v) = (2, 2) ·" }).waitFor({ timeout });
  const hover = await page.locator("#hover").textContent();
  for (const part of ["ball", "λ = 2.00000", "point (0.000, 0.000, 2.000)", "normal (-1.000, 0.000, 0.000)"]) {
    check(hover.includes(part), `the hover line lacks ${part}: ${hover}`);
  }
  // λ as depth: (4, 2) is the lecture's nearest hit (λ ≈ 1.017), white; (2, 2) the
  // farthest (λ = 2), the ramp's dark end.
  await page.locator("#hits-mode").selectOption("depth");
  await page.locator("#legend", { hasText: "near" }).waitFor({ timeout });
  c = await pixel("#hits-canvas", 4, 2);
  check(c.join() === "255,255,255,255", `depth at (4, 2): ${c}`);
  c = await pixel("#hits-canvas", 2, 2);
  check(c.join() === "55,55,55,255", `depth at (2, 2): ${c}`);
  // Normals as colours: (2, 2)'s normal is (−1, 0, 0); (3, 1)'s has a negative y.
  await page.locator("#hits-mode").selectOption("normals");
  await page.locator("#legend", { hasText: "+x" }).waitFor({ timeout });
  c = await pixel("#hits-canvas", 2, 2);
  check(c.join() === "0,128,128,255", `normal at (2, 2): ${c}`);
  c = await pixel("#hits-canvas", 3, 3);
  check(c[1] > 128 && c[2] < 128, `normal at (3, 3): ${c}`);
  await page.screenshot({ path: `${shots}/hit-data-normals.png` });
  check(accepts.length === 1, "each view is drawn from the one download");
  await page.locator("#hits-mode").selectOption("image");
  await byId("hits-view").waitFor({ state: "hidden", timeout });
});

await step("an invalid scene's render shows its problem document", async () => {
  await setScene('{"version": 1, "image": {"width": 0, "height": 5}, "camera": {}, "objects": [], "lights": []}');
  await byId("render-button").click();
  await page.waitForFunction(() => document.querySelector("[data-testid=render-status]").classList.contains("error"), null, { timeout });
  const text = await byId("render-status").textContent();
  check(/invalid|scene/i.test(text), `the status says ${text}`);
  check(await page.locator("#problems li", { hasText: "/image/width" }).count() > 0, "the problem lists /image/width");
});

await step("cancel a large render and the ray counter stops", async () => {
  await setScene(readFileSync(`${fixtures}/big.json`, "utf8"));
  const before = await rays();
  await byId("render-button").click();
  const deadline = Date.now() + timeout;
  while ((await rays()) <= before) {
    check(Date.now() < deadline, "the render never started");
    await new Promise((r) => setTimeout(r, 100));
  }
  // Band by band: the top rows are on screen while the bottom ones are still tracing.
  await page.waitForFunction(() => {
    const live = document.querySelector("#live");
    if (live.hidden || live.height !== 4096) return false;
    const g = live.getContext("2d");
    return g.getImageData(0, 0, 1, 1).data[3] === 255;
  }, null, { timeout });
  const bottom = await pixel("#live", 0, 4095);
  check(bottom[3] === 0, `the last row is drawn before the render ends: ${bottom}`);
  check(/rendering .* rows/.test(await byId("render-status").textContent()), "the status counts rows");
  await page.screenshot({ path: `${shots}/band-by-band.png` });
  await page.getByRole("button", { name: "Cancel" }).click();
  await page.locator("[data-testid=render-status]", { hasText: "cancelled" }).waitFor({ timeout });
  // A render stops within a tile of its client leaving: let that tile finish.
  let settled = await rays();
  for (let i = 0; i < 50; i++) {
    await new Promise((r) => setTimeout(r, 500));
    const now = await rays();
    if (now === settled) break;
    settled = now;
  }
  await new Promise((r) => setTimeout(r, 1500));
  const after = await rays();
  check(after === settled, `the counter went on from ${settled} to ${after}`);
  check(after > before, "some rays were traced");
});

await step("the showcase scene, rendered and traced", async () => {
  const value = await page.$eval("[data-testid=example-picker]", (s) =>
    [...s.options].find((o) => o.textContent.startsWith("showcase")).value);
  await byId("example-picker").selectOption(value);
  await page.waitForFunction(() => window.studio.view.state.doc.toString().includes("1024"), null, { timeout });
  await byId("render-button").click();
  await page.waitForFunction(() => {
    const img = document.querySelector("[data-testid=render-image]");
    return img.complete && img.naturalWidth === 1024 && /rendered/.test(document.querySelector("[data-testid=render-status]").textContent);
  }, null, { timeout: 120_000 });
  const box = await byId("render-image").boundingBox();
  check(box.width <= 1024 && box.width > 200, `the image fits the stage (${box.width} px wide)`);
  await page.mouse.click(box.x + box.width * 0.5, box.y + box.height * 0.55);
  await page.waitForFunction(() => /Pixel \(/.test(document.querySelector("[data-testid=trace-panel]").textContent), null, { timeout });
});

await step("the dark theme follows the system", async () => {
  await page.emulateMedia({ colorScheme: "dark" });
  const bg = await page.evaluate(() => getComputedStyle(document.body).backgroundColor);
  const [r, g, b] = bg.match(/\d+/g).map(Number);
  check(r + g + b < 150, `the background is ${bg}`);
});

await step("the page raised no error", async () => {
  check(errors.length === 0, errors.join("\n"));
});

await browser.close();
console.log(`screenshots: ${shots}`);
console.log(`${passed} passed, ${failed} failed`);
process.exit(failed ? 1 : 0);
