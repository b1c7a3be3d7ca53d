// The Khronos glTF-Validator on one .glb: prints its report as JSON.
// Run with node, the validator installed where NODE_PATH (or node_modules
// beside this file) finds it: npm install gltf-validator.
import { readFile } from 'node:fs/promises';
import { createRequire } from 'node:module';

const require = createRequire(import.meta.url);
const validator = require('gltf-validator');
const path = process.argv[2];
const data = new Uint8Array(await readFile(path));
const report = await validator.validateBytes(data, { maxIssues: 100, uri: path });
process.stdout.write(JSON.stringify(report));
