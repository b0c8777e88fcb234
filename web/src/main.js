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
import { schemaCompletion, schemaHover } from "./schema.js";
import schema from "../../api/scene.schema.json";

const $ = (id) => document.getElementById(id);
const STORE = "raytile.studio.scene";
const state = { width: 0, height: 0, zoom: 1, selected: null, controller: null, url: null };

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
      clearTimeout(saveTimer);
      saveTimer = setTimeout(() => localStorage.setItem(STORE, view.state.doc.toString()), 300);
    }),
    EditorView.contentAttributes.of({ "aria-label": "Scene document (JSON)" }),
  ],
});
window.studio = { view };

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
  // Another scene: the last grading and trace were of the one before.
  $("grade-result").replaceChildren();
  $("grade-file").value = "";
  $("diff").hidden = true;
  $("submission").hidden = true;
  $("wipe").hidden = true;
  $("trace").textContent = "Render, then click a pixel to see how its colour was computed.";
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
}

/** Posts the scene and shows the PNG as it streams: Chromium draws a truncated PNG's
 * rows as far as they go, so re-showing the bytes so far paints band after band. */
async function render() {
  if (state.controller) state.controller.abort();
  const controller = new AbortController();
  state.controller = controller;
  $("cancel").disabled = false;
  $("render").disabled = true;
  const start = performance.now();
  const before = await raysTraced();
  status("rendering…");
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
    // A new image: the old one's hit data and selected pixel no longer apply.
    hits = null;
    state.selected = null;
    $("hits-canvas").hidden = true;
    $("legend").replaceChildren();
    applyZoom(true);
    const total = state.width * state.height;
    const reader = res.body.getReader();
    const parts = [];
    let bytes = 0;
    let shown = 0;
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      parts.push(value);
      bytes += value.length;
      const now = performance.now();
      if (now - shown > 120) {
        shown = now;
        showBlob(parts);
        status(`rendering ${state.width}×${state.height} (${total} px) · ${(bytes / 1024).toFixed(1)} KiB · ${((now - start) / 1000).toFixed(1)} s`);
      }
    }
    showBlob(parts);
    const rays = (await raysTraced()) - before;
    const secs = ((performance.now() - start) / 1000).toFixed(2);
    status(`rendered ${state.width}×${state.height} in ${secs} s · ${Number.isFinite(rays) ? rays.toLocaleString() : "?"} rays`);
  } catch (e) {
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
  for (const el of [$("image"), $("hits-canvas")]) { el.style.width = `${w}px`; el.style.height = `${h}px`; }
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
  if (state.selected) {
    const [u, v] = state.selected;
    g.strokeStyle = "#ffcc00";
    g.lineWidth = 2;
    g.strokeRect(u * z + 1, v * z + 1, Math.max(z - 2, 2), Math.max(z - 2, 2));
  }
}
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
  if (tree.ok) $("trace-tree").replaceChildren(treeOf("ray tree (JSON)", await tree.json(), true));
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
for (const id of ["image", "hits-canvas"]) {
  $(id).addEventListener("click", (e) => { const p = pixelAt(e); if (p) trace(...p); });
  $(id).addEventListener("mousemove", (e) => {
    const p = pixelAt(e);
    $("hover").textContent = p ? `(u, v) = (${p[0]}, ${p[1]})${hitLine(p)}` : "";
  });
}

// ---- hit data ---------------------------------------------------------------------

let hits = null;
function hitLine([u, v]) {
  if (!hits) return "";
  const p = hits.pixels.find((q) => q.u === u && q.v === v);
  if (!p || !p.hit) return " · miss";
  const f = (a) => a.map((x) => x.toFixed(3)).join(", ");
  return ` · ${p.name ?? `#${p.object}`} · λ = ${p.lambda.toPrecision(6)} · point (${f(p.point)}) · normal (${f(p.normal)})`;
}

const PALETTE = ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"];
async function showHits() {
  const canvas = $("hits-canvas");
  if (!canvas.hidden) { canvas.hidden = true; $("legend").replaceChildren(); return; }
  status("hit data…");
  const res = await fetch("/v1/hits", {
    method: "POST", headers: { "content-type": "application/json", accept: "application/json" },
    body: view.state.doc.toString(),
  });
  if (!res.ok) { status((await problemOf(res)).line, true); return; }
  hits = await res.json();
  state.width = hits.width; state.height = hits.height;
  canvas.width = hits.region.width; canvas.height = hits.region.height;
  const g = canvas.getContext("2d");
  const names = new Map();
  for (const p of hits.pixels) {
    if (!p.hit) continue;
    names.set(p.object, p.name ?? `#${p.object}`);
    g.fillStyle = PALETTE[p.object % PALETTE.length];
    g.fillRect(p.u - hits.region.x, p.v - hits.region.y, 1, 1);
  }
  $("legend").replaceChildren(...[...names].map(([i, n]) => {
    const s = document.createElement("span");
    const sw = document.createElement("i");
    sw.style.background = PALETTE[i % PALETTE.length];
    s.append(sw, n);
    return s;
  }));
  canvas.hidden = false;
  applyZoom(!$("image").src);
  status(`hit data: ${hits.pixels.filter((p) => p.hit).length} of ${hits.pixels.length} pixels hit`);
}
$("hits").addEventListener("click", showHits);

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
