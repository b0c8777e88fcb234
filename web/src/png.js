// A PNG decoded while it arrives, so the render appears band by band as the server
// streams it. /v1/render writes 8-bit RGB, not interlaced (src/format/png.rs); its IDAT
// payload is one zlib stream, which the browser's DecompressionStream("deflate")
// inflates as bytes come. Rows are unfiltered as soon as they are whole and handed on
// in bands. Any other PNG is refused (`push` answers false) and the caller shows the
// whole file instead.

const SIGNATURE = [137, 80, 78, 71, 13, 10, 26, 10];

/** Paeth's predictor (PNG, filter type 4). */
function paeth(a, b, c) {
  const p = a + b - c;
  const pa = Math.abs(p - a);
  const pb = Math.abs(p - b);
  const pc = Math.abs(p - c);
  return pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
}

/** Undoes row filter `type` in place (`bpp` bytes a pixel, `prev` the row above). */
export function unfilter(type, row, prev, bpp) {
  const n = row.length;
  switch (type) {
    case 0: return true;
    case 1: for (let i = bpp; i < n; i++) row[i] = (row[i] + row[i - bpp]) & 255; return true;
    case 2: for (let i = 0; i < n; i++) row[i] = (row[i] + prev[i]) & 255; return true;
    case 3:
      for (let i = 0; i < n; i++) row[i] = (row[i] + (((i >= bpp ? row[i - bpp] : 0) + prev[i]) >> 1)) & 255;
      return true;
    case 4:
      for (let i = 0; i < n; i++) {
        const a = i >= bpp ? row[i - bpp] : 0;
        const c = i >= bpp ? prev[i - bpp] : 0;
        row[i] = (row[i] + paeth(a, prev[i], c)) & 255;
      }
      return true;
    default: return false;
  }
}

/**
 * A streaming decoder. `onHeader(width, height)` once the header is read, then
 * `onRows(y, count, rgba)` for each band of whole rows (RGBA, ready for an ImageData).
 * `push(bytes)` feeds what arrived and answers false once the file turns out to be a
 * PNG this decoder does not draw (or no PNG); `end()` resolves when every row that
 * arrived has been drawn.
 */
export function pngStream({ onHeader, onRows }) {
  let pending = new Uint8Array(0);
  let stage = "signature";
  let left = 0;
  let type = "";
  let refused = false;
  let width = 0;
  let height = 0;
  let stride = 0;
  let writer = null;
  let inflated = Promise.resolve();
  // The row being filled (its filter byte first), the row above, the next row's index.
  let row = null;
  let fill = 0;
  let prev = null;
  let y = 0;

  function start() {
    const ds = new DecompressionStream("deflate");
    writer = ds.writable.getWriter();
    const reader = ds.readable.getReader();
    inflated = (async () => {
      for (;;) {
        const { done, value } = await reader.read();
        if (done) return;
        rows(value);
      }
    })().catch(() => { /* a cut stream: what arrived is drawn */ });
  }

  /** Inflated bytes → whole rows, unfiltered, converted to RGBA and drawn as one band. */
  function rows(bytes) {
    const first = y;
    const band = [];
    let at = 0;
    while (at < bytes.length && y < height) {
      const take = Math.min(stride + 1 - fill, bytes.length - at);
      row.set(bytes.subarray(at, at + take), fill);
      fill += take;
      at += take;
      if (fill < stride + 1) break;
      const pixels = row.subarray(1);
      if (!unfilter(row[0], pixels, prev, 3)) { refused = true; return; }
      prev.set(pixels);
      band.push(prev.slice());
      fill = 0;
      y++;
    }
    if (!band.length) return;
    const rgba = new Uint8ClampedArray(band.length * width * 4);
    let k = 0;
    for (const r of band) {
      for (let i = 0; i < stride; i += 3) {
        rgba[k++] = r[i]; rgba[k++] = r[i + 1]; rgba[k++] = r[i + 2]; rgba[k++] = 255;
      }
    }
    onRows(first, band.length, rgba);
  }

  function header(d) {
    const v = new DataView(d.buffer, d.byteOffset, d.byteLength);
    width = v.getUint32(0);
    height = v.getUint32(4);
    const [depth, colour, , , interlace] = d.subarray(8, 13);
    if (depth !== 8 || colour !== 2 || interlace !== 0 || !width || !height) return false;
    stride = width * 3;
    row = new Uint8Array(stride + 1);
    prev = new Uint8Array(stride);
    onHeader(width, height);
    start();
    return true;
  }

  function push(bytes) {
    if (refused) return false;
    const data = new Uint8Array(pending.length + bytes.length);
    data.set(pending);
    data.set(bytes, pending.length);
    let pos = 0;
    for (;;) {
      const avail = data.length - pos;
      if (stage === "signature") {
        if (avail < 8) break;
        if (SIGNATURE.some((b, i) => data[pos + i] !== b)) { refused = true; return false; }
        pos += 8;
        stage = "head";
      } else if (stage === "head") {
        if (avail < 8) break;
        left = new DataView(data.buffer, pos, 4).getUint32(0);
        type = String.fromCharCode(...data.subarray(pos + 4, pos + 8));
        pos += 8;
        if (!writer && type !== "IHDR") { refused = true; return false; }
        stage = "data";
      } else if (stage === "data") {
        if (type === "IHDR") {
          if (avail < left) break;
          if (!header(data.subarray(pos, pos + left))) { refused = true; return false; }
        } else if (type === "IDAT") {
          // The payload goes on as it comes, not a whole chunk at a time.
          const take = Math.min(left, avail);
          if (take) writer.write(data.slice(pos, pos + take)).catch(() => {});
          pos += take;
          left -= take;
          if (left) break;
        } else {
          const skip = Math.min(left, avail);
          pos += skip;
          left -= skip;
          if (left) break;
        }
        if (type === "IHDR") pos += left;
        left = 4;
        stage = "crc";
      } else if (stage === "crc") {
        if (avail < 4) break;
        pos += 4;
        if (type === "IEND") { writer.close().catch(() => {}); stage = "end"; } else stage = "head";
      } else {
        break;
      }
    }
    pending = data.slice(pos);
    return !refused;
  }

  return {
    push,
    /** Resolves once every row that arrived is drawn. */
    async end() {
      if (writer && stage !== "end") writer.close().catch(() => {});
      await inflated;
      return !refused && y === height;
    },
    /** Stops inflating (the render was cancelled). */
    abort() { writer?.abort().catch(() => {}); },
  };
}
