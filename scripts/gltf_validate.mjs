// Runs the Khronos glTF-Validator (npm package gltf-validator, installed by scripts/setup.sh into .tools/)
// on one .gltf / .glb file and prints its JSON report on stdout. Exit code 0 when the report has no errors,
// 1 when it has some, 2 when the file or the validator cannot be read.
// Usage: node scripts/gltf_validate.mjs scene.glb
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, "..", ".tools", "package.json"));
const file = process.argv[2];
if (!file) {
  console.error("usage: node scripts/gltf_validate.mjs FILE.glb");
  process.exit(2);
}
let validator;
try {
  validator = require("gltf-validator");
} catch (err) {
  console.error(`gltf-validator is not installed in .tools/ (run scripts/setup.sh): ${err.message}`);
  process.exit(2);
}
try {
  const data = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(data, {
    uri: path.basename(file),
    maxIssues: 0,
    externalResourceFunction: (uri) => readFile(path.join(path.dirname(file), decodeURIComponent(uri))),
  });
  console.log(JSON.stringify(report, null, 2));
  process.exit(report.issues.numErrors > 0 ? 1 : 0);
} catch (err) {
  console.error(`cannot validate ${file}: ${err.message ?? err}`);
  process.exit(2);
}
