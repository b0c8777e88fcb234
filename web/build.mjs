// Bundles the studio into dist/: studio.js (the page's code and CodeMirror), studio.css,
// index.html, and a gzipped twin of each (Node's gzip writes no time stamp, so the same
// sources always give the same bytes, which is what CI's check of dist/ relies on).
import { build } from "esbuild";
import { copyFileSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { gzipSync } from "node:zlib";

const here = new URL(".", import.meta.url).pathname;
const dist = `${here}dist`;
mkdirSync(dist, { recursive: true });

await build({
  entryPoints: [`${here}src/main.js`],
  bundle: true,
  minify: true,
  format: "esm",
  target: ["es2022"],
  legalComments: "none",
  outfile: `${dist}/studio.js`,
  logLevel: "warning",
});
copyFileSync(`${here}src/studio.css`, `${dist}/studio.css`);
copyFileSync(`${here}src/index.html`, `${dist}/index.html`);

let total = 0;
for (const f of ["index.html", "studio.js", "studio.css"]) {
  const bytes = readFileSync(`${dist}/${f}`);
  total += bytes.length;
  writeFileSync(`${dist}/${f}.gz`, gzipSync(bytes, { level: 9 }));
}
if (total >= 1 << 20) {
  console.error(`the page is ${total} bytes: more than 1 MB`);
  process.exit(1);
}
console.log(`dist/: ${total} bytes`);
