// The studio: a scene editor, a streamed render, a pixel's trace, hit data and grading,
// all through this server's own /v1 routes. Every API error is a problem document
// (RFC 9457): it is shown as its title, detail and problems say, the scene's problems at
// their JSON pointers in the editor.
import { basicSetup, EditorView } from "codemirror";
import { keymap } from "@codemirror/view";
import { Compartment, Prec } from "@codemirror/state";
import { oneDark } from "@codemirror/theme-one-dark";
import { json, jsonParseLinter } from "@codemirror/lang-json";
import { linter, lintGutter } from "@codemirror/lint";
import { autocompletion } from "@codemirror/autocomplete";
import { rangeAt } from "./pointer.js";
import { pngStream } from "./png.js";
import { PALETTE, paint, parseHitsNpy } from "./hits.js";
import { schemaCompletion, schemaHover } from "./schema.js";
import schema from "../../api/scene.schema.json";

const $ = (id) => document.getElementById(id);
const STORE = "raytile.studio.scene";
const state = { width: 0, height: 0, zoom: 1, selected: null, rays: null, controller: null, url: null };

// ---- problems ---------------------------------------------------------------------

/** A failed answer as one line, and its scene problems (pointer, message) if any. */
async function problemOf(res) {
  let doc = null;
  try { doc = await res.json(); } catch { /* not a problem document */ }
  if (!doc || typeof doc !== "object") {
    return { line: `HTTP ${res.status}`, problems: [] };
  }
  const where = doc.line ? ` (line ${doc.line}, column ${doc.column})` : "";
  const line = `${doc.title ?? `HTTP ${res.status}`}: ${doc.detail ?? ""}${where}`;
  return { line, problems: Array.isArray(doc.problems) ? doc.problems : [] };
}

function showProblems(problems) {
  const list = $("problems");
  list.replaceChildren();
  for (const p of problems) {
    const li = document.createElement("li");
    const code = document.createElement("code");
    code.textContent = p.pointer || "/";
    li.append(code, p.message);
    li.tabIndex = 0;
    const go = () => {
      const r = rangeAt(view.state, p.pointer ?? "");
      view.dispatch({ selection: { anchor: r.from, head: r.to }, scrollIntoView: true });
      view.focus();
    };
    li.addEventListener("click", go);
    li.addEventListener("keydown", (e) => e.key === "Enter" && go());
    list.append(li);
  }
}

function status(text, error = false) {
  $("status").textContent = text;
  $("status").classList.toggle("error", error);
}

// ---- the editor -------------------------------------------------------------------

/** JSON syntax first; a document that parses is then checked by the server itself. */
const syntax = jsonParseLinter();
async function lintScene(v) {
  const local = syntax(v);
  if (local.length) { showProblems([]); return local; }
  const res = await fetch("/v1/validate", {
    method: "POST", headers: { "content-type": "application/json" }, body: v.state.doc.toString(),
  }).catch(() => null);
  if (!res || res.ok) { showProblems([]); return []; }
  const { line, problems } = await problemOf(res);
  if (v.state.doc.toString() !== view.state.doc.toString()) return [];
  showProblems(problems);
  if (!problems.length) return [{ from: 0, to: 0, severity: "error", message: line }];
  return problems.map((p) => ({ ...rangeAt(v.state, p.pointer ?? ""), severity: "error", message: `${p.pointer}: ${p.message}` }));
}

// The editor's colours follow the system's theme, as the page's do.
const dark = matchMedia("(prefers-color-scheme: dark)");
const theme = new Compartment();
dark.addEventListener("change", () => view.dispatch({ effects: theme.reconfigure(dark.matches ? oneDark : []) }));

let saveTimer = 0;
const view = new EditorView({
  parent: $("editor"),
  doc: localStorage.getItem(STORE) ?? "",
  extensions: [
    basicSetup,
    theme.of(dark.matches ? oneDark : []),
    json(),
    lintGutter(),
    linter(lintScene, { delay: 400 }),
    autocompletion({ override: [schemaCompletion(schema)] }),
    schemaHover(schema),
    Prec.highest(keymap.of([{ key: "Mod-Enter", run: () => { render(); return true; } }])),
    EditorView.updateListener.of((u) => {
      if (!u.docChanged) return;
      // Hit data is of the scene it was asked for: another document asks again.
      if (hits) clearHits();
      clearTimeout(saveTimer);
      saveTimer = setTimeout(() => localStorage.setItem(STORE, view.state.doc.toString()), 300);
    }),
    EditorView.contentAttributes.of({ "aria-label": "Scene document (JSON)" }),
  ],
});
window.studio = { view, selected: () => state.selected };

function setScene(text) {
  view.dispatch({ changes: { from: 0, to: view.state.doc.length, insert: text } });
  localStorage.setItem(STORE, text);
}

async function loadExamples() {
  const res = await fetch("/v1/scenes");
  if (!res.ok) { status((await problemOf(res)).line, true); return; }
  const { scenes } = await res.json();
  for (const s of scenes) {
    const o = document.createElement("option");
    o.value = s.href;
    o.textContent = `${s.name} — ${s.width}×${s.height}, ${s.objects} objects`;
    $("examples").append(o);
  }
  if (!view.state.doc.length && scenes.length) await pick(scenes[0].href);
}

async function pick(href) {
  const res = await fetch(href);
  if (!res.ok) { status((await problemOf(res)).line, true); return; }
  setScene(await res.text());
  clearHits();
  // Another scene: the last grading and trace were of the one before.
  $("grade-result").replaceChildren();
  $("grade-file").value = "";
  $("diff").hidden = true;
  $("submission").hidden = true;
  $("wipe").hidden = true;
  $("trace").textContent = "Render, then click a pixel to see how its colour was computed.";
  $("trace-tree").replaceChildren();
  state.selected = null;
  state.rays = null;
  rayLegend();
  status(`loaded ${href.split("/").pop()}`);
}

$("examples").addEventListener("change", (e) => e.target.value && pick(e.target.value));
$("download").addEventListener("click", () => {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([view.state.doc.toString()], { type: "application/json" }));
  a.download = "scene.json";
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 1000);
});

// ---- render -----------------------------------------------------------------------

async function raysTraced() {
  const text = await fetch("/metrics").then((r) => r.text()).catch(() => "");
  const m = text.match(/^raytile_rays_traced_total (\S+)$/m);
  return m ? Number(m[1]) : NaN;
}

function showBlob(parts) {
  const url = URL.createObjectURL(new Blob(parts, { type: "image/png" }));
  if (state.url) URL.revokeObjectURL(state.url);
  state.url = url;
  $("image").src = url;
  return $("image").decode().catch(() => {});
}

/** The canvas the streamed rows are drawn into, in place of the image until it ends. */
function liveCanvas(w, h) {
  const live = $("live");
  live.width = w;
  live.height = h;
  live.getContext("2d").clearRect(0, 0, w, h);
  live.hidden = false;
  $("image").hidden = true;
  return live;
}

function progress(done, total) {
  const bar = $("progress");
  bar.hidden = done >= total;
  bar.max = total;
  bar.value = done;
}

/** Posts the scene and shows the PNG as it streams: each band of rows is decoded and
 * drawn as it arrives (png.js); a PNG that decoder does not draw is shown whole, the
 * browser drawing a truncated file's rows as far as they go. */
async function render() {
  if (state.controller) state.controller.abort();
  const controller = new AbortController();
  state.controller = controller;
  $("cancel").disabled = false;
  $("render").disabled = true;
  const start = performance.now();
  const before = await raysTraced();
  status("rendering…");
  let decoder = null;
  try {
    const res = await fetch("/v1/render", {
      method: "POST", headers: { "content-type": "application/json" },
      body: view.state.doc.toString(), signal: controller.signal,
    });
    if (!res.ok) {
      const { line, problems } = await problemOf(res);
      showProblems(problems);
      status(line, true);
      return;
    }
    state.width = Number(res.headers.get("x-raytile-width"));
    state.height = Number(res.headers.get("x-raytile-height"));
    // A new image: the old one's hit data, selected pixel and rays no longer apply.
    clearHits();
    state.selected = null;
    state.rays = null;
    rayLegend();
    applyZoom(true);
    const total = state.width * state.height;
    const g = liveCanvas(state.width, state.height).getContext("2d");
    let rows = 0;
    decoder = pngStream({
      onHeader: () => {},
      onRows: (y, n, rgba) => {
        g.putImageData(new ImageData(rgba, state.width, n), 0, y);
        rows = y + n;
      },
    });
    let streaming = true;
    const reader = res.body.getReader();
    const parts = [];
    let bytes = 0;
    let shown = 0;
    progress(0, state.height);
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      parts.push(value);
      bytes += value.length;
      if (streaming && !decoder.push(value)) {
        streaming = false;
        $("live").hidden = true;
        $("image").hidden = false;
      }
      const now = performance.now();
      if (now - shown > 120) {
        shown = now;
        if (!streaming) showBlob(parts);
        const secs = ((now - start) / 1000).toFixed(1);
        const where = streaming ? `${rows} of ${state.height} rows` : `${(bytes / 1024).toFixed(1)} KiB`;
        progress(rows, state.height);
        status(`rendering ${state.width}×${state.height} (${total} px) · ${where} · ${secs} s`);
      }
    }
    if (streaming) await decoder.end();
    await showBlob(parts);
    $("image").hidden = false;
    $("live").hidden = true;
    progress(1, 1);
    const rays = (await raysTraced()) - before;
    const secs = ((performance.now() - start) / 1000).toFixed(2);
    status(`rendered ${state.width}×${state.height} in ${secs} s · ${Number.isFinite(rays) ? rays.toLocaleString() : "?"} rays`);
  } catch (e) {
    decoder?.abort();
    status(e.name === "AbortError" ? "cancelled" : `render failed: ${e.message}`, e.name !== "AbortError");
  } finally {
    if (state.controller === controller) state.controller = null;
    $("cancel").disabled = true;
    $("render").disabled = false;
  }
}
$("render").addEventListener("click", render);
$("cancel").addEventListener("click", () => state.controller?.abort());
document.addEventListener("keydown", (e) => {
  if ((e.ctrlKey || e.metaKey) && e.key === "Enter") { e.preventDefault(); render(); }
});

// ---- zoom and the pixel grid ------------------------------------------------------

function applyZoom(fit) {
  if (!state.width) return;
  if (fit) {
    // Small images by whole steps (each pixel a crisp square), large ones shrunk to fit.
    const stage = $("stage");
    const fits = Math.min((stage.clientWidth - 40) / state.width, (stage.clientHeight - 40) / state.height);
    state.zoom = fits >= 1 ? Math.min(64, Math.floor(fits)) : Math.max(fits, 0.05);
    $("zoom").value = Math.max(1, Math.round(state.zoom));
  }
  const w = state.width * state.zoom;
  const h = state.height * state.zoom;
  for (const el of [$("image"), $("live"), $("hits-canvas")]) { el.style.width = `${w}px`; el.style.height = `${h}px`; }
  $("zoom-out").textContent = state.zoom >= 1 ? `${state.zoom}×` : `${Math.round(state.zoom * 100)} %`;
  drawGrid();
}

/** At 8× and more, the lecture's pixel grid; the selected pixel outlined. */
function drawGrid() {
  const c = $("grid");
  const z = state.zoom;
  c.width = state.width * z;
  c.height = state.height * z;
  const g = c.getContext("2d");
  g.clearRect(0, 0, c.width, c.height);
  if (z >= 8) {
    g.strokeStyle = "rgba(128,128,128,.55)";
    g.lineWidth = 1;
    g.beginPath();
    for (let x = 0; x <= state.width; x++) { g.moveTo(x * z + 0.5, 0); g.lineTo(x * z + 0.5, c.height); }
    for (let y = 0; y <= state.height; y++) { g.moveTo(0, y * z + 0.5); g.lineTo(c.width, y * z + 0.5); }
    g.stroke();
  }
  if (state.rays && $("show-rays").checked) drawRays(g, z);
  if (state.selected) {
    const [u, v] = state.selected;
    g.strokeStyle = "#ffcc00";
    g.lineWidth = 2;
    g.strokeRect(u * z + 1, v * z + 1, Math.max(z - 2, 2), Math.max(z - 2, 2));
  }
}
/** How each kind of ray is drawn: colour, and dashes for shadow rays. */
const RAY_STYLE = {
  primary: ["#ffcc00", []],
  reflected: ["#35d0ff", []],
  refracted: ["#ff5ad2", []],
  total_internal_reflection: ["#ff9a3c", []],
  shadow: ["#f4f4f4", [5, 4]],
};

/** The part of segment a→b inside the rectangle [x0, x1] × [y0, y1] (Liang–Barsky),
 * or null: a ray may end far off the image (at a vanishing point, or cut where it
 * passes the eye), and drawing it only needs the part on the canvas. */
function clip([ax, ay], [bx, by], x0, y0, x1, y1) {
  let t0 = 0;
  let t1 = 1;
  const dx = bx - ax;
  const dy = by - ay;
  for (const [p, q] of [[-dx, ax - x0], [dx, x1 - ax], [-dy, ay - y0], [dy, y1 - ay]]) {
    if (p === 0) { if (q < 0) return null; continue; }
    const t = q / p;
    if (p < 0) { if (t > t1) return null; t0 = Math.max(t0, t); } else { if (t < t0) return null; t1 = Math.min(t1, t); }
  }
  return [[ax + t0 * dx, ay + t0 * dy], [ax + t1 * dx, ay + t1 * dy], t1 === 1];
}

/** The selected pixel's rays where they land on the image, as the server projected them
 * (the trace's `screen`): shadow rays dashed, a blocked one ending in a cross. */
function drawRays(g, z) {
  g.save();
  g.lineCap = "round";
  const m = 4 * Math.max(state.width, state.height);
  for (const r of state.rays) {
    const [colour, dash] = RAY_STYLE[r.role] ?? RAY_STYLE.primary;
    const seg = clip(r.from, r.to, -m, -m, state.width + m, state.height + m);
    if (!seg) continue;
    const [[ax, ay], [bx, by], whole] = seg;
    g.setLineDash(dash);
    g.lineWidth = 2.5;
    g.strokeStyle = "rgba(0,0,0,.55)";
    g.beginPath(); g.moveTo(ax * z, ay * z); g.lineTo(bx * z, by * z); g.stroke();
    g.lineWidth = 1.5;
    g.strokeStyle = colour;
    g.stroke();
    g.setLineDash([]);
    g.fillStyle = colour;
    g.beginPath(); g.arc(ax * z, ay * z, 3, 0, 2 * Math.PI); g.fill();
    if (!whole) continue;
    if (r.ends === "blocked") {
      g.strokeStyle = "#ff4d4d";
      g.lineWidth = 2;
      g.beginPath();
      g.moveTo(bx * z - 4, by * z - 4); g.lineTo(bx * z + 4, by * z + 4);
      g.moveTo(bx * z + 4, by * z - 4); g.lineTo(bx * z - 4, by * z + 4);
      g.stroke();
    } else if (r.ends === "hit" || r.ends === "light") {
      g.beginPath(); g.arc(bx * z, by * z, r.ends === "light" ? 5 : 3, 0, 2 * Math.PI); g.fill();
    }
  }
  g.restore();
}

function rayLegend() {
  const kinds = [...new Set((state.rays ?? []).map((r) => r.role))];
  $("ray-legend").replaceChildren(...kinds.map((k) => {
    const n = state.rays.filter((r) => r.role === k).length;
    return swatch(RAY_STYLE[k][0], `${k.replace(/_/g, " ")}${n > 1 ? ` ×${n}` : ""}`);
  }));
}
$("show-rays").addEventListener("change", drawGrid);

$("zoom").addEventListener("input", (e) => { state.zoom = Number(e.target.value); applyZoom(false); });

function pixelAt(e) {
  const r = e.currentTarget.getBoundingClientRect();
  const u = Math.floor(((e.clientX - r.left) / r.width) * state.width);
  const v = Math.floor(((e.clientY - r.top) / r.height) * state.height);
  return u >= 0 && v >= 0 && u < state.width && v < state.height ? [u, v] : null;
}

// ---- trace ------------------------------------------------------------------------

async function trace(u, v) {
  state.selected = [u, v];
  for (const b of document.querySelectorAll("#grade-result [data-pixel]")) {
    b.setAttribute("aria-pressed", String(b.dataset.pixel === `${u},${v}`));
  }
  state.rays = null;
  rayLegend();
  drawGrid();
  $("trace").textContent = `tracing pixel (${u}, ${v})…`;
  const res = await fetch(`/v1/trace?u=${u}&v=${v}&format=text`, {
    method: "POST", headers: { "content-type": "application/json" }, body: view.state.doc.toString(),
  });
  $("trace").textContent = res.ok ? await res.text() : (await problemOf(res)).line;
  if (!res.ok) return;
  const tree = await fetch(`/v1/trace?u=${u}&v=${v}`, {
    method: "POST", headers: { "content-type": "application/json" }, body: view.state.doc.toString(),
  });
  if (!tree.ok) return;
  const explanation = await tree.json();
  $("trace-tree").replaceChildren(treeOf("ray tree (JSON)", explanation, true));
  // Still the pixel asked about (another click may have come meanwhile).
  if (state.selected?.[0] !== u || state.selected?.[1] !== v) return;
  state.rays = explanation.screen ?? null;
  rayLegend();
  drawGrid();
}

/** A JSON value as nested <details>, each object or array folded until opened. */
function treeOf(label, value, open = false) {
  if (value === null || typeof value !== "object") {
    const leaf = el("div", "", "leaf");
    leaf.append(el("span", `${label}: `, "key"), el("span", JSON.stringify(value), "val"));
    return leaf;
  }
  const d = el("details");
  d.open = open;
  const n = Array.isArray(value) ? `[${value.length}]` : `{${Object.keys(value).length}}`;
  d.append(el("summary", `${label} ${n}`));
  // Children are built when first opened: a deep tree stays cheap until explored.
  const fill = () => {
    if (d.dataset.filled) return;
    d.dataset.filled = "1";
    for (const [k, v] of Object.entries(value)) d.append(treeOf(k, v));
  };
  if (open) fill();
  d.addEventListener("toggle", fill);
  return d;
}
for (const id of ["image", "live", "hits-canvas"]) {
  $(id).addEventListener("click", (e) => { const p = pixelAt(e); if (p) trace(...p); });
  $(id).addEventListener("mousemove", (e) => {
    const p = pixelAt(e);
    $("hover").textContent = p ? `(u, v) = (${p[0]}, ${p[1]})${hitLine(p)}` : "";
  });
}

// ---- hit data ---------------------------------------------------------------------

/** The last hit data, with the scene's object names; `null` until asked for. */
let hits = null;

function clearHits() {
  hits = null;
  $("hits-mode").value = "image";
  $("hits-canvas").hidden = true;
  $("legend").replaceChildren();
}

function hitLine([u, v]) {
  if (!hits) return "";
  const [x, y] = [u - hits.x, v - hits.y];
  if (x < 0 || y < 0 || x >= hits.width || y >= hits.height) return "";
  const i = y * hits.width + x;
  const o = hits.object[i];
  if (o < 0) return " · miss";
  const f = (a) => [...a.subarray(3 * i, 3 * i + 3)].map((c) => c.toFixed(3)).join(", ");
  return ` · ${hits.names[o] ?? `#${o}`} · λ = ${hits.lambda[i].toPrecision(6)} · point (${f(hits.point)}) · normal (${f(hits.normal)})`;
}

/** The names of the scene's objects by index, from the document being edited. */
function objectNames() {
  try {
    return (JSON.parse(view.state.doc.toString()).objects ?? []).map((o, i) => o?.name ?? `#${i}`);
  } catch {
    return [];
  }
}

function swatch(colour, text) {
  const s = el("span");
  const sw = el("i");
  sw.style.background = colour;
  s.append(sw, text);
  return s;
}

/** Draws the hit data as `mode` shows it, and its legend. */
function drawHits(mode) {
  const canvas = $("hits-canvas");
  canvas.width = hits.width;
  canvas.height = hits.height;
  const { rgba, lo, hi } = paint(hits, mode);
  canvas.getContext("2d").putImageData(new ImageData(rgba, hits.width, hits.height), 0, 0);
  const legend = $("legend");
  if (mode === "objects") {
    const seen = [...new Set(hits.object)].filter((o) => o >= 0).sort((a, b) => a - b);
    legend.replaceChildren(...seen.map((o) => swatch(PALETTE[o % PALETTE.length], hits.names[o] ?? `#${o}`)));
  } else if (mode === "depth") {
    const bar = el("span", "", "ramp");
    legend.replaceChildren(el("span", Number.isFinite(lo) ? `λ ${lo.toPrecision(4)} near` : "no hits"), bar, el("span", Number.isFinite(hi) ? `far λ ${hi.toPrecision(4)}` : ""));
  } else {
    legend.replaceChildren(swatch("rgb(255,128,128)", "+x"), swatch("rgb(128,255,128)", "+y"), swatch("rgb(128,128,255)", "+z"), el("span", "normal (x, y, z) → (r, g, b)"));
  }
  canvas.hidden = false;
}

/** The view selector: the render, or its hit data as objects, depth or normals. */
async function showHits(mode) {
  if (mode === "image") { $("hits-canvas").hidden = true; $("legend").replaceChildren(); return; }
  if (!hits) {
    status("hit data…");
    const res = await fetch("/v1/hits", {
      method: "POST", headers: { "content-type": "application/json", accept: "application/x-npy" },
      body: view.state.doc.toString(),
    });
    if (!res.ok) { status((await problemOf(res)).line, true); $("hits-mode").value = "image"; return; }
    const [fw, fh] = [res.headers.get("x-raytile-width"), res.headers.get("x-raytile-height")].map(Number);
    try {
      hits = { ...parseHitsNpy(await res.arrayBuffer()), names: objectNames() };
    } catch (e) {
      status(`hit data: ${e.message}`, true);
      $("hits-mode").value = "image";
      return;
    }
    if (!state.width) { state.width = fw; state.height = fh; applyZoom(true); }
    let hit = 0;
    for (const o of hits.object) if (o >= 0) hit++;
    status(`hit data: ${hit} of ${hits.object.length} pixels hit`);
  }
  if ($("hits-mode").value !== mode) return;
  drawHits(mode);
  applyZoom(!$("image").src);
}
$("hits-mode").addEventListener("change", (e) => showHits(e.target.value));

// ---- grade ------------------------------------------------------------------------

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined) e.textContent = text;
  if (cls) e.className = cls;
  return e;
}

$("grade-file").addEventListener("change", async (e) => {
  const file = e.target.files[0];
  if (!file) return;
  const out = $("grade-result");
  out.replaceChildren(el("p", `grading ${file.name}…`));
  const form = new FormData();
  form.append("scene", new Blob([view.state.doc.toString()], { type: "application/json" }), "scene.json");
  form.append("submission", file, file.name);
  const res = await fetch("/v1/grade?inline_diff=true", { method: "POST", body: form });
  if (!res.ok) { out.replaceChildren(el("p", (await problemOf(res)).line, "problem")); return; }
  const r = await res.json();
  out.replaceChildren(
    el("div", r.pass ? "PASS" : "FAIL", `verdict ${r.pass ? "pass" : "fail"}`),
    el("p", `score ${r.score.value.toFixed(3)} (${r.score.scoring}) · ${r.failing_pixels} of ${r.pixels} pixels fail (${(100 * r.failing_share).toFixed(1)} %)`),
    el("p", r.summary),
  );
  for (const m of r.diagnosis?.mistakes ?? []) {
    const p = el("p");
    p.append(el("strong", `${m.title} (${(100 * m.matches).toFixed(0)} % match): `), m.explanation);
    out.append(p);
  }
  if (r.worst?.length) {
    const ol = el("ol");
    for (const w of r.worst) {
      const li = el("li");
      const b = el("button", `(${w.u}, ${w.v})`);
      b.title = `Select pixel (${w.u}, ${w.v}) and show its trace`;
      b.dataset.pixel = `${w.u},${w.v}`;
      b.setAttribute("aria-pressed", "false");
      b.addEventListener("click", () => trace(w.u, w.v));
      li.append(b, ` ${w.pass ? "passes" : w.failures.join(", ")}`);
      ol.append(li);
    }
    out.append(el("p", "worst pixels:"), ol);
  }
  if (r.diff_png_base64) {
    $("diff").src = `data:image/png;base64,${r.diff_png_base64}`;
    $("diff").hidden = false;
  }
  $("wipe").hidden = true;
  if (file.type.startsWith("image/")) {
    const url = URL.createObjectURL(file);
    $("submission").src = url;
    $("submission").hidden = false;
    // The reference is the render on screen, when it is of this scene's size.
    const img = $("image");
    if (img.src && img.naturalWidth === r.width && img.naturalHeight === r.height) {
      $("wipe-ref").src = img.src;
      $("wipe-sub").src = url;
      $("wipe").hidden = false;
      wipe();
    }
  }
});

/** The submission shown right of the slider, the reference left of it. */
function wipe() {
  $("wipe-sub").style.clipPath = `inset(0 0 0 ${$("wipe-at").value}%)`;
}
$("wipe-at").addEventListener("input", wipe);

loadExamples();
