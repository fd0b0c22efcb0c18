// FuseFlow live frame decoder: both binary frame formats of /ws (version 1 "raw", version 2
// "compact"; docs/live.md has them byte by byte). No dependencies: the compact streams are zlib,
// inflated by the browser's DecompressionStream("deflate") (Chromium, Firefox, Safari 16.4+,
// Node 18+). decodeFrame(arrayBuffer) -> Promise of {version, number, m, pointsIn, xyz
// (Float32Array, 3 m, metres), rgb (Uint8ClampedArray, 3 m), latency, fuseMs}.
"use strict";
(function (root) {
  const f32 = (dv, o) => dv.getFloat32(o, true);
  function decodeRaw(buf, dv) {
    const head = dv.getUint16(6, true), m = dv.getUint32(12, true);
    const lo = [f32(dv, 16), f32(dv, 20), f32(dv, 24)];
    const ext = [0, 1, 2].map((i) => Math.max(f32(dv, 28 + 4 * i) - lo[i], 1e-6));
    const q = new Int16Array(buf, head, 3 * m), xyz = new Float32Array(3 * m);
    for (let i = 0; i < 3 * m; i++) xyz[i] = lo[i % 3] + ((q[i] + 32768) / 65535) * ext[i % 3];
    return { m, pointsIn: m, xyz, rgb: new Uint8Array(buf, head + 6 * m, 3 * m), latency: f32(dv, 40), fuseMs: f32(dv, 44) };
  }
  async function inflate(bytes) {
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }
  const POP = new Uint8Array(256).map((_, b) => (b & 1) + ((b >> 1) & 1) + ((b >> 2) & 1) + ((b >> 3) & 1) +
    ((b >> 4) & 1) + ((b >> 5) & 1) + ((b >> 6) & 1) + ((b >> 7) & 1));
  function octree(occ, levels, m) {
    // breadth first from the root: bit k of a node's byte = child k (k = 4 x + 2 y + z) occupied
    let xs = new Uint32Array(1), ys = new Uint32Array(1), zs = new Uint32Array(1), pos = 0;
    for (let l = 0; l < levels; l++) {
      const n = xs.length;
      if (pos + n > occ.length) throw new Error("occupancy stream too short");
      let total = 0;
      for (let i = 0; i < n; i++) total += POP[occ[pos + i]];
      const nx = new Uint32Array(total), ny = new Uint32Array(total), nz = new Uint32Array(total);
      let k = 0;
      for (let i = 0; i < n; i++) {
        const b = occ[pos + i], x = xs[i] * 2, y = ys[i] * 2, z = zs[i] * 2;
        for (let c = 0; c < 8; c++) if (b & (1 << c)) { nx[k] = x + (c >> 2); ny[k] = y + ((c >> 1) & 1); nz[k] = z + (c & 1); k++; }
      }
      pos += n; xs = nx; ys = ny; zs = nz;
    }
    if (xs.length !== m) throw new Error("octree gives " + xs.length + " points, header says " + m);
    return [xs, ys, zs];
  }
  async function decodeCompact(buf, dv) {
    const H = dv.getUint16(6, true), m = dv.getUint32(12, true);
    const origin = [f32(dv, 20), f32(dv, 24), f32(dv, 28)], step = f32(dv, 32);
    const levels = dv.getUint8(44), ls = dv.getUint8(45), cs = dv.getUint8(46), blk = dv.getUint8(47);
    const s1 = dv.getUint32(52, true), s2 = dv.getUint32(56, true), s3 = dv.getUint32(60, true);
    const [occ, luma, chroma] = await Promise.all([
      inflate(new Uint8Array(buf, H, s1)), inflate(new Uint8Array(buf, H + s1, s2)),
      inflate(new Uint8Array(buf, H + s1 + s2, s3))]);
    const xyz = new Float32Array(3 * m), rgb = new Uint8ClampedArray(3 * m);  // clamps and rounds
    if (m > 0) {
      const [xs, ys, zs] = octree(occ, levels, m);
      for (let i = 0; i < m; i++) {
        xyz[3 * i] = origin[0] + (xs[i] + 0.5) * step;
        xyz[3 * i + 1] = origin[1] + (ys[i] + 0.5) * step;
        xyz[3 * i + 2] = origin[2] + (zs[i] + 0.5) * step;
      }
      const nb = Math.ceil(m / blk);
      let yq = 0, cb = 0, cr = 0;
      for (let i = 0; i < m; i++) {
        yq = (yq + luma[i]) & 255;
        if (i % blk === 0) {
          const b = i / blk;
          cb = (cb + chroma[b]) & 255; cr = (cr + chroma[nb + b]) & 255;
        }
        const Y = yq * ls, Cb = (cb << 24 >> 24) * cs, Cr = (cr << 24 >> 24) * cs;  // int8 chroma
        const r = Y + Cr, bl = Y + Cb, g = (256 * Y - 77 * r - 29 * bl) / 150;
        rgb[3 * i] = r; rgb[3 * i + 1] = g; rgb[3 * i + 2] = bl;
      }
    }
    return { m, pointsIn: dv.getUint32(16, true), xyz, rgb, latency: f32(dv, 36), fuseMs: f32(dv, 40) };
  }
  async function decodeFrame(buf) {
    if (buf.byteLength < 8) throw new Error("frame shorter than a header");
    const dv = new DataView(buf);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    const version = magic === "FFLV" ? dv.getUint16(4, true) : 0;
    let frame;
    if (version === 1) frame = decodeRaw(buf, dv);
    else if (version === 2) frame = await decodeCompact(buf, dv);
    else throw new Error("unknown frame format");
    return Object.assign(frame, { version, number: dv.getUint32(8, true) });
  }
  const api = { decodeFrame };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.FuseFlowDecode = api;
})(typeof self !== "undefined" ? self : globalThis);
