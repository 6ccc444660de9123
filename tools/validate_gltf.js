// Validates a glTF or GLB file with the Khronos glTF validator (npm `gltf-validator`) and prints
// its issue counts as JSON; exits 1 when it finds errors.
//   npm install --prefix target/gltf-validator gltf-validator
//   NODE_PATH=target/gltf-validator/node_modules node tools/validate_gltf.js FILE.glb
const fs = require('fs');
const validator = require('gltf-validator');
const file = process.argv[2];
validator
  // Every issue counted (maxIssues 0); the texture coordinates and the light-map texture that
  // only the `lightmap` extras name are reported as unused objects, which is expected.
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    maxIssues: 0,
    ignoredIssues: ['UNUSED_OBJECT'],
  })
  .then((report) => {
    const i = report.issues;
    const errors = i.messages.filter((m) => m.severity === 0).slice(0, 10);
    console.log(JSON.stringify({
      validator: report.validatorVersion,
      errors: i.numErrors,
      warnings: i.numWarnings,
      infos: i.numInfos,
      first_errors: errors,
    }));
    process.exit(i.numErrors > 0 ? 1 : 0);
  })
  .catch((e) => {
    console.error(String(e));
    process.exit(2);
  });
