#!/usr/bin/env node
// Validate .gltf files with the Khronos glTF validator (npm package gltf-validator, pinned in
// package.json; install it with `npm ci` in this folder).
//
//   node tools/gltf-validate/validate.mjs FILE.gltf [FILE.gltf ...]
//
// External resources (buffers, images) are loaded relative to each file, so the referenced
// PNGs are decoded and checked too; a missing one is an IO_ERROR. Prints one JSON array on
// stdout, one entry per file: {file, validatorVersion, issues, info}, where `issues` is the
// report's issues object (numErrors, numWarnings, numInfos, numHints, messages: every
// message, none truncated) and `info` its summary (resources, counts). One summary line per
// file goes to stderr. Exit status: 0 no errors, 1 an error in some file, 2 a file that
// could not be read or parsed as glTF at all, or bad arguments.

import { readFile } from "node:fs/promises";
import path from "node:path";
import validator from "gltf-validator";

async function validate(file) {
  const data = new Uint8Array(await readFile(file));
  const folder = path.dirname(path.resolve(file));
  const report = await validator.validateBytes(data, {
    uri: file,
    format: "gltf",
    maxIssues: 0, // every message: the caller decides which ones matter
    writeTimestamp: false,
    externalResourceFunction: async (uri) =>
      new Uint8Array(await readFile(path.resolve(folder, decodeURIComponent(uri)))),
  });
  return {
    file,
    validatorVersion: report.validatorVersion,
    issues: report.issues,
    info: report.info ?? null,
  };
}

const files = process.argv.slice(2);
if (files.length === 0 || files.some((f) => f.startsWith("-"))) {
  console.error("usage: node validate.mjs FILE.gltf [FILE.gltf ...]");
  process.exit(2);
}
const results = [];
let status = 0;
for (const file of files) {
  try {
    const result = await validate(file);
    const i = result.issues;
    console.error(
      `${file}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints`,
    );
    results.push(result);
    if (i.numErrors > 0) status = Math.max(status, 1);
  } catch (error) {
    // validateBytes rejects when the bytes are not glTF at all; readFile when the file is missing
    console.error(`${file}: cannot validate: ${error?.message ?? error}`);
    results.push({ file, error: String(error?.message ?? error) });
    status = 2;
  }
}
console.log(JSON.stringify(results, null, 2));
process.exit(status);
