// FuseFlow live: decodes a key frame's geometry stream beside the page's thread (decode.js's
// createDecoder({ worker }) posts the jobs and decodes the colour stream meanwhile). A module
// worker: new Worker(new URL("decode-worker.js", import.meta.url), { type: "module" }).
// Job: {id, version, geo (ArrayBuffer: the geometry stream), levels, m, origin, step}; answer:
// {id, xyz, occ, first} with their buffers transferred, or {id, error}.
import "./decode.js";

const { keyGeometry } = self.FuseFlowDecode;
self.onmessage = (e) => {
  const { id, version, geo, levels, m, origin, step } = e.data;
  try {
    const g = keyGeometry(version, new Uint8Array(geo), levels, m, origin, step);
    self.postMessage({ id, xyz: g.xyz, occ: g.occ, first: g.first }, [g.xyz.buffer, g.occ.buffer, g.first.buffer]);
  } catch (err) {
    self.postMessage({ id, error: String((err && err.message) || err) });
  }
};
