#!/usr/bin/env node
// Validate glTF/GLB files with the Khronos glTF-Validator (npm package `gltf-validator`):
// prints the issue counts and every error or warning, exits 1 if any file has an error.
//
//   cd "$(mktemp -d)" && npm install gltf-validator && \
//     NODE_PATH=$PWD/node_modules node /path/to/kdmap/tools/validate_gltf.js out/scene.glb
const fs = require('fs');
const path = require('path');
const validator = require('gltf-validator');

async function check(file) {
  const data = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(data, {
    uri: file,
    externalResourceFunction: (uri) =>
      Promise.resolve(new Uint8Array(fs.readFileSync(path.resolve(path.dirname(file), decodeURIComponent(uri))))),
  });
  const i = report.issues;
  console.log(`${file}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints` +
    ` (${report.info ? `${report.info.totalTriangleCount} triangles, ${report.info.materialCount} materials, ` +
    `${report.info.resources ? report.info.resources.length : 0} resources` : 'no info'})`);
  for (const m of i.messages) {
    if (m.severity <= 1) console.log(`  ${m.severity === 0 ? 'error' : 'warning'} ${m.code} at ${m.pointer}: ${m.message}`);
  }
  return i.numErrors;
}

(async () => {
  let errors = 0;
  for (const f of process.argv.slice(2)) errors += await check(f);
  process.exit(errors > 0 ? 1 : 0);
})();
