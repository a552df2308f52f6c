// Validate a .gltf or .glb file with the Khronos glTF validator; print the JSON report on stdout.
// Usage: node validate.mjs FILE [MAX_ISSUES]
// Exit status: 0 when a report was produced (read report.issues.numErrors), 2 on bad input.
import { readFile } from 'node:fs/promises';
import path from 'node:path';
import validator from 'gltf-validator';

const file = process.argv[2];
if (!file) {
  console.error('usage: node validate.mjs FILE [MAX_ISSUES]');
  process.exit(2);
}
const maxIssues = Number(process.argv[3] ?? 200);
const dir = path.dirname(path.resolve(file));

try {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues,
    externalResourceFunction: async (uri) => {
      const target = path.resolve(dir, decodeURIComponent(uri));
      if (path.relative(dir, target).startsWith('..')) throw new Error(`resource outside the asset folder: ${uri}`);
      return new Uint8Array(await readFile(target));
    },
  });
  process.stdout.write(JSON.stringify(report));
} catch (error) {
  console.error(`${file}: ${error}`);
  process.exit(2);
}
