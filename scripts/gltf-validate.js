// node scripts/gltf-validate.js VALIDATOR_DIR FILE.glb|FILE.gltf
// Runs the Khronos glTF validator's API (validateBytes) on one file and prints its report's
// issues as JSON ({numErrors, numWarnings, numInfos, numHints, messages}); exit 0 without errors,
// 1 with errors, 3 when the validator could not run.
const fs = require('fs');
const [dir, file] = process.argv.slice(2);
const validator = require(dir);
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), { maxIssues: 0, writeTimestamp: false })
  .then((report) => {
    console.log(JSON.stringify(report.issues));
    if (report.issues.numErrors > 0) process.exitCode = 1;
  })
  .catch((e) => { console.error(String(e)); process.exit(3); });
