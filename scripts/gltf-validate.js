// node scripts/gltf-validate.js VALIDATOR_DIR FILE.glb|FILE.gltf
// Runs the Khronos glTF validator's API (validateBytes) on one file and prints its report's
// issues as JSON ({numErrors, numWarnings, numInfos, numHints, messages}); exit 0 without errors,
// 1 with errors, 3 when the validator could not run.
// A .gltf's side files (its buffer's URI) are read from the file's folder.
const fs = require('fs');
const path = require('path');
const [dir, file] = process.argv.slice(2);
const validator = require(dir);
const externalResourceFunction = (uri) =>
  new Promise((resolve, reject) => {
    fs.readFile(path.join(path.dirname(file), decodeURIComponent(uri)), (err, data) =>
      err ? reject(err.toString()) : resolve(new Uint8Array(data)));
  });
validator
  .validateBytes(new Uint8Array(fs.readFileSync(file)), {
    maxIssues: 0, writeTimestamp: false, uri: path.basename(file), externalResourceFunction,
  })
  .then((report) => {
    console.log(JSON.stringify(report.issues));
    if (report.issues.numErrors > 0) process.exitCode = 1;
  })
  .catch((e) => { console.error(String(e)); process.exit(3); });
