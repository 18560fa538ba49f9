// Validates a .glb with the Khronos glTF validator and prints the issue counts as JSON.
// Used by tests/mesh_io.rs; the validator is installed under target/npm by that test.
const validator = require('gltf-validator');
const fs = require('fs');
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
validator
  .validateBytes(data, { maxIssues: 100 })
  .then((r) => {
    console.log(JSON.stringify({
      errors: r.issues.numErrors,
      warnings: r.issues.numWarnings,
      infos: r.issues.numInfos,
      messages: r.issues.messages,
    }));
  })
  .catch((e) => {
    console.error(e);
    process.exit(2);
  });
