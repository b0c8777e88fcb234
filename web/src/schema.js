// Completion and hover docs from the scene's JSON Schema (api/scene.schema.json, bundled):
// the property names an object may have with their descriptions, and the values of a
// field that takes one of a few. Validation is the server's own (/v1/validate), so that
// the editor never disagrees with what a render will say.
import { hoverTooltip } from "@codemirror/view";
import { syntaxTree } from "@codemirror/language";
import { pathAt } from "./pointer.js";

function deref(root, s) {
  for (let i = 0; s && s.$ref && i < 32; i++) {
    s = s.$ref.replace(/^#\//, "").split("/").reduce((o, k) => o?.[k.replace(/~1/g, "/").replace(/~0/g, "~")], root);
  }
  return s ?? {};
}

/** Every alternative `s` stands for (oneOf, anyOf, allOf, then/else), flattened. */
function branches(root, s, out = []) {
  s = deref(root, s);
  if (typeof s !== "object" || out.includes(s)) return out;
  out.push(s);
  for (const k of ["oneOf", "anyOf", "allOf"]) for (const b of s[k] ?? []) branches(root, b, out);
  for (const k of ["then", "else"]) if (s[k]) branches(root, s[k], out);
  return out;
}

/** The schemas that may describe the value at `path`. */
export function schemasAt(root, path) {
  let here = branches(root, root);
  for (const key of path) {
    const next = [];
    for (const s of here) {
      if (s.properties?.[key]) branches(root, s.properties[key], next);
      else if (/^\d+$/.test(key)) {
        const pre = s.prefixItems?.[Number(key)];
        if (pre) branches(root, pre, next);
        else if (s.items && typeof s.items === "object") branches(root, s.items, next);
      }
    }
    here = next;
  }
  return here;
}

function properties(root, path) {
  const seen = new Map();
  for (const s of schemasAt(root, path)) {
    for (const [name, p] of Object.entries(s.properties ?? {})) {
      if (!seen.has(name)) seen.set(name, deref(root, p).description ?? p.description ?? "");
    }
  }
  return seen;
}

export function schemaCompletion(root) {
  return (ctx) => {
    const word = ctx.matchBefore(/"?[\w-]*/);
    if (!word || (word.from === word.to && !ctx.explicit)) return null;
    const { path, inName, objectNode } = pathAt(ctx.state, ctx.pos);
    if (inName && objectNode) {
      const present = new Set();
      for (const p of objectNode.getChildren("Property")) {
        const n = p.getChild("PropertyName");
        if (n) present.add(ctx.state.sliceDoc(n.from + 1, n.to - 1));
      }
      const options = [...properties(root, path)]
        .filter(([name]) => !present.has(name))
        .map(([name, info]) => ({ label: `"${name}"`, apply: `"${name}": `, type: "property", info: info || undefined }));
      return options.length ? { from: word.from, options } : null;
    }
    const values = new Set();
    for (const s of schemasAt(root, path)) {
      for (const v of s.enum ?? []) values.add(JSON.stringify(v));
      if ("const" in s) values.add(JSON.stringify(s.const));
    }
    return values.size ? { from: word.from, options: [...values].map((v) => ({ label: v, type: "enum" })) } : null;
  };
}

export function schemaHover(root) {
  return hoverTooltip((view, pos) => {
    const node = syntaxTree(view.state).resolveInner(pos, 1);
    if (node.name !== "PropertyName") return null;
    const name = view.state.sliceDoc(node.from + 1, node.to - 1);
    const { path } = pathAt(view.state, node.from);
    const info = properties(root, path).get(name);
    if (!info) return null;
    return {
      pos: node.from, end: node.to, above: true,
      create() {
        const dom = document.createElement("div");
        dom.className = "cm-schema-doc";
        dom.textContent = info;
        return { dom };
      },
    };
  });
}
