// Hit data from /v1/hits as NPY (docs/spec/hit-data.md, NPY), read into typed arrays:
// one record of 101 bytes a pixel, the region's rows in order. The page asks for NPY
// rather than JSON because a frame's hit data is then a few typed arrays, not an object
// a pixel.

/** The record's fields in the order and with the types the server writes them. */
const DESCR = "[('u', '<i4'), ('v', '<i4'), ('hit', '|b1'), ('object', '<i4'), ('lambda', '<f8'), " +
  "('point', '<f8', (3,)), ('object_point', '<f8', (3,)), ('normal', '<f8', (3,)), ('face', '<U2')]";
const RECORD = 101;

/**
 * An NPY file of hit records → `{ x, y, width, height, object, lambda, point, normal }`
 * (the region's place in the frame and size, then per pixel of the region in row-major
 * order: the object's index or −1, λ, and the world point and normal, three numbers
 * each; NaN for a miss). Throws on any other file.
 */
export function parseHitsNpy(buffer) {
  const bytes = new Uint8Array(buffer);
  const magic = String.fromCharCode(...bytes.subarray(0, 6));
  if (magic !== "\x93NUMPY") throw new Error("not an NPY file");
  const dv = new DataView(buffer);
  const major = bytes[6];
  const headerLen = major === 1 ? dv.getUint16(8, true) : dv.getUint32(8, true);
  const start = (major === 1 ? 10 : 12) + headerLen;
  const header = new TextDecoder().decode(bytes.subarray(major === 1 ? 10 : 12, start));
  if (!header.includes(DESCR) || !header.includes("'fortran_order': False")) {
    throw new Error("NPY records not laid out as hit data");
  }
  const shape = header.match(/'shape': \((\d+), (\d+)\)/);
  if (!shape) throw new Error("NPY hit data without a 2-D shape");
  const [height, width] = [Number(shape[1]), Number(shape[2])];
  const n = width * height;
  if (bytes.length < start + n * RECORD) throw new Error("NPY hit data cut short");
  const object = new Int32Array(n);
  const lambda = new Float64Array(n);
  const point = new Float64Array(3 * n);
  const normal = new Float64Array(3 * n);
  for (let i = 0; i < n; i++) {
    const o = start + i * RECORD;
    object[i] = bytes[o + 8] ? dv.getInt32(o + 9, true) : -1;
    lambda[i] = dv.getFloat64(o + 13, true);
    for (let k = 0; k < 3; k++) {
      point[3 * i + k] = dv.getFloat64(o + 21 + 8 * k, true);
      normal[3 * i + k] = dv.getFloat64(o + 69 + 8 * k, true);
    }
  }
  const x = n ? dv.getInt32(start, true) : 0;
  const y = n ? dv.getInt32(start + 4, true) : 0;
  return { x, y, width, height, object, lambda, point, normal };
}

export const PALETTE = ["#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f", "#bab0ac"];
const RGB = PALETTE.map((c) => [1, 3, 5].map((i) => parseInt(c.slice(i, i + 2), 16)));

/**
 * The hit data drawn as RGBA for one view: `objects` (each object its palette colour),
 * `depth` (λ as grey, the nearest hit white and the farthest dark), `normals` (each
 * component of the unit normal from −1..1 to 0..255, as normal maps do). Misses stay
 * transparent.
 */
export function paint(h, mode) {
  const n = h.width * h.height;
  const out = new Uint8ClampedArray(4 * n);
  let lo = Infinity;
  let hi = -Infinity;
  if (mode === "depth") {
    for (let i = 0; i < n; i++) {
      if (h.object[i] < 0) continue;
      lo = Math.min(lo, h.lambda[i]);
      hi = Math.max(hi, h.lambda[i]);
    }
  }
  for (let i = 0; i < n; i++) {
    if (h.object[i] < 0) continue;
    let c;
    if (mode === "depth") {
      const t = hi > lo ? (h.lambda[i] - lo) / (hi - lo) : 0;
      const g = Math.round(255 - 200 * t);
      c = [g, g, g];
    } else if (mode === "normals") {
      c = [0, 1, 2].map((k) => Math.round((h.normal[3 * i + k] + 1) * 127.5));
    } else {
      c = RGB[h.object[i] % RGB.length];
    }
    out.set(c, 4 * i);
    out[4 * i + 3] = 255;
  }
  return { rgba: out, lo, hi };
}
