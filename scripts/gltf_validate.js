// The Khronos glTF-Validator (npm `gltf-validator`) on one .glb, for tests/gltf.rs:
//   NODE_PATH=<dir with node_modules> node scripts/gltf_validate.js FILE.glb
// Prints the validator's issue counts and messages as one JSON object.
const fs = require("fs");
const validator = require("gltf-validator");

const file = process.argv[2];
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 100 })
  .then((report) => {
    const issues = report.issues;
    console.log(JSON.stringify({
      validator: report.validatorVersion,
      errors: issues.numErrors,
      warnings: issues.numWarnings,
      infos: issues.numInfos,
      hints: issues.numHints,
      messages: issues.messages.map((m) => `${m.code} ${m.pointer || ""}: ${m.message}`),
    }));
  })
  .catch((e) => {
    console.error(`gltf-validator: ${e}`);
    process.exit(1);
  });
