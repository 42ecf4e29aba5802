// Validates a glTF asset with the Khronos glTF validator (npm package gltf-validator) and exits
// non-zero when it reports any error; 77 (a skip for ctest) when the package is not installed.
// Usage: node validate_gltf.mjs FILE.gltf
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import { execSync } from "node:child_process";

let validator;
try {
  const require = createRequire(import.meta.url);
  let path = "gltf-validator";
  try { require.resolve(path); } catch { path = execSync("npm root -g").toString().trim() + "/gltf-validator"; }
  validator = require(path);
} catch {
  console.error("validate_gltf: the npm package gltf-validator is not installed (scripts/install-deps.sh installs it); skipped");
  process.exit(77);
}
const file = process.argv[2];
const report = await validator.validateBytes(new Uint8Array(await readFile(file)), { uri: file, maxIssues: 100 });
const issues = report.issues;
console.log(`${file}: ${issues.numErrors} errors, ${issues.numWarnings} warnings, ${issues.numInfos} infos, ${issues.numHints} hints`);
for (const m of issues.messages) console.log(`  [${["error", "warning", "info", "hint"][m.severity]}] ${m.code} ${m.pointer ?? ""}: ${m.message}`);
process.exit(issues.numErrors > 0 ? 1 : 0);
