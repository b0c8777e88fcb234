// JSON pointers (RFC 6901) to ranges of the document, through the editor's syntax tree:
// the server names each problem by its pointer, and the editor marks that value. A
// pointer that goes past what exists (a missing field) marks the deepest value it reaches.
import { syntaxTree } from "@codemirror/language";

const VALUES = new Set(["Object", "Array", "String", "Number", "True", "False", "Null"]);

function values(node) {
  const out = [];
  for (let c = node.firstChild; c; c = c.nextSibling) if (VALUES.has(c.name)) out.push(c);
  return out;
}

function propertyName(state, prop) {
  const n = prop.getChild("PropertyName");
  if (!n) return null;
  try { return JSON.parse(state.sliceDoc(n.from, n.to)); } catch { return null; }
}

/** The pointer's tokens: `/a~1b/0` → ["a/b", "0"]. */
export function tokens(pointer) {
  if (!pointer) return [];
  return pointer.split("/").slice(1).map((t) => t.replace(/~1/g, "/").replace(/~0/g, "~"));
}

/** The range of the value at `pointer` (or of the deepest value on its way). */
export function rangeAt(state, pointer) {
  const tree = syntaxTree(state);
  let node = values(tree.topNode)[0];
  if (!node) return { from: 0, to: Math.min(state.doc.length, 1) };
  for (const t of tokens(pointer)) {
    let next = null;
    if (node.name === "Object") {
      for (const p of node.getChildren("Property")) {
        if (propertyName(state, p) === t) { next = values(p)[0] ?? p; break; }
      }
    } else if (node.name === "Array" && /^\d+$/.test(t)) {
      next = values(node)[Number(t)] ?? null;
    }
    if (!next) break;
    node = next;
  }
  // A whole object or array marks only its first line, not the rest of the document.
  const end = node.name === "Object" || node.name === "Array" ? Math.min(node.to, state.doc.lineAt(node.from).to) : node.to;
  return { from: node.from, to: Math.max(end, node.from + 1) };
}

/** The path of keys and indices from the top to the node at `pos`, and whether `pos` is
 * where a property name goes (inside an object but not in a value). */
export function pathAt(state, pos) {
  const tree = syntaxTree(state);
  let node = tree.resolveInner(pos, -1);
  const path = [];
  let inName = false;
  if (node.name === "PropertyName") { inName = true; node = node.parent; }
  let objectNode = null;
  for (let n = node; n; n = n.parent) {
    if (n.name === "Object" && !objectNode) objectNode = n;
    const parent = n.parent;
    if (!parent) break;
    if (parent.name === "Property" && VALUES.has(n.name)) path.unshift(propertyName(state, parent));
    if (parent.name === "Array" && VALUES.has(n.name)) path.unshift(String(values(parent).findIndex((c) => c.from === n.from)));
  }
  return { path, inName: inName || node.name === "Object", objectNode };
}
