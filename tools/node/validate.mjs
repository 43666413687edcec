// Validates glTF/GLB files with the Khronos glTF-Validator (npm `gltf-validator`, pinned in
// package.json). Usage: node validate.mjs FILE.glb [...]
// Prints one JSON line per file: {"file","errors","warnings","infos","hints","messages":[...]}
// (messages: the errors and warnings, code + pointer + text). Exit status 1 if any file has an
// error or a warning, 2 on a usage or I/O problem.
import { readFile } from 'node:fs/promises';
import validator from 'gltf-validator';

const files = process.argv.slice(2);
if (files.length === 0) {
  console.error('usage: node validate.mjs FILE.glb [...]');
  process.exit(2);
}
let bad = false;
for (const file of files) {
  let data;
  try {
    data = new Uint8Array(await readFile(file));
  } catch (e) {
    console.error(`${file}: ${e.message}`);
    process.exit(2);
  }
  const report = await validator.validateBytes(data, {
    uri: file,
    maxIssues: 0,
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not allowed`)),
  });
  const issues = report.issues;
  const messages = issues.messages
    .filter((m) => m.severity <= 1)
    .slice(0, 50)
    .map((m) => ({ severity: m.severity === 0 ? 'error' : 'warning', code: m.code, pointer: m.pointer, message: m.message }));
  const line = {
    file,
    errors: issues.numErrors,
    warnings: issues.numWarnings,
    infos: issues.numInfos,
    hints: issues.numHints,
    validatorVersion: report.validatorVersion,
    messages,
  };
  console.log(JSON.stringify(line));
  if (issues.numErrors > 0 || issues.numWarnings > 0) bad = true;
}
process.exit(bad ? 1 : 0);
