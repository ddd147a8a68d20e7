// Bundle the console into the Python package (service/console/static/), which pip installs.
import { build } from "esbuild";
import { cpSync, mkdirSync, rmSync } from "node:fs";

const out = new URL("../service/console/static/", import.meta.url).pathname;
rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });
await build({
  entryPoints: ["src/main.js"],
  bundle: true,
  minify: true,
  format: "esm",
  target: ["es2022"],
  outfile: `${out}app.js`,
  legalComments: "linked", // three.js's MIT licence text ships beside the bundle
  logLevel: "warning",
});
cpSync("src/index.html", `${out}index.html`);
cpSync("src/app.css", `${out}app.css`);
