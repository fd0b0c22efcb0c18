// FuseFlow live frame decoder: the binary frame formats of /ws (version 1 "raw", versions 3-7 and 2
// "compact"; docs/live.md has them byte by byte). No dependencies: versions 3-7 are range coded
// (the decoder below mirrors fuseflow/live/codec_kernels.py decision for decision); version 2's zlib
// streams are inflated by the browser's DecompressionStream("deflate") (Chromium, Firefox,
// Safari 16.4+, Node 18+). decodeFrame(arrayBuffer) -> Promise of {version, number, m, pointsIn,
// xyz (Float32Array, 3 m, metres), rgb (Uint8ClampedArray, 3 m), latency, fuseMs}; it rejects
// (an Error) a truncated, corrupt or inconsistent frame. A version-4 or 6 frame (a delta) decodes only
// with createDecoder().decodeFrame, fed the stream's frames in order (it holds the last one).
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
  // ---- version 3: LZMA's adaptive binary range decoder over context-modelled decisions ----
  const CRC = new Int32Array(256).map((_, n) => {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320 ^ (c >>> 1) : c >>> 1;
    return c;
  });
  function crc32(bytes) {
    let c = -1;
    for (let i = 0; i < bytes.length; i++) c = CRC[(c ^ bytes[i]) & 255] ^ (c >>> 8);
    return (c ^ -1) >>> 0;
  }
  // range decoder state: Float64Array [range, code, bytes read] (a typed array: no boxed numbers)
  function rangeDecoder(bytes) {
    const s = new Float64Array(3);
    s[0] = 0xFFFFFFFF;
    for (let i = 1; i < 5; i++) s[1] = s[1] * 256 + (i < bytes.length ? bytes[i] : 0);  // byte 0: always 0
    s[2] = 5;
    return s;
  }
  function bit(s, bytes, probs, c) {
    // one decision with the adaptive probability probs[c] (11 bits, adapted by 1/32)
    const p = probs[c];
    let range = s[0], code = s[1], b = 0;
    const bound = (range >>> 11) * p;
    if (code < bound) { range = bound; probs[c] = p + ((2048 - p) >> 5); }
    else { code -= bound; range -= bound; probs[c] = p - (p >> 5); b = 1; }
    if (range < 16777216) {
      let pos = s[2];
      do {
        range *= 256;
        code = ((code << 8) | (pos < bytes.length ? bytes[pos] : 0)) >>> 0;
        pos++;
      } while (range < 16777216);
      s[2] = pos;
    }
    s[0] = range; s[1] = code;
    return b;
  }
  // occupancy contexts (codec_kernels.geo_contexts): BASE[(last * 64 + nb) * 8 + k] + EXTRA[k * 128 + below]
  const BASE = new Int32Array(1024), EXTRA = new Int32Array(1024);
  for (let last = 0; last < 2; last++) for (let nb = 0; nb < 64; nb++) for (let k = 0; k < 8; k++) {
    const bx = k >> 2, by = (k >> 1) & 1, bz = k & 1;
    const adj = (((nb >> bx) & 1) << 2) | (((nb >> (2 + by)) & 1) << 1) | ((nb >> (4 + bz)) & 1);
    const far = ((nb >> (1 - bx)) & 1) + ((nb >> (3 - by)) & 1) + ((nb >> (5 - bz)) & 1);
    BASE[(last * 64 + nb) * 8 + k] = (((last * 8 + adj) * 4 + far) * 8 + k) * 8;
  }
  for (let k = 0; k < 8; k++) for (let below = 0; below < (1 << k); below++)
    EXTRA[k * 128 + below] = (((below >> (k ^ 4)) & 1) + ((below >> (k ^ 2)) & 1) + ((below >> (k ^ 1)) & 1)) * 2 + (below ? 1 : 0);
  const SINGLE = 4096, TREE = 4096 + 128, P_CHILD = 5248, P_SINGLE = P_CHILD + 8192, P_TREE = P_SINGLE + 256;
  const GEO_CONTEXTS = P_TREE + 3072, RES = 32, SPLIT = 30 * RES, COL_CONTEXTS = SPLIT + 2, ESCAPE = 14, MAX_PREFIX = 16;
  const NO_REF = { occ: new Uint8Array(0), first: new Int32Array(0), q: new Int32Array(0) };
  function refFirst(occ, levels) {
    // where each node's first child is in a reference octree (breadth-first bytes, root first):
    // the next depth's position, or at the last depth the leaf index (codec_kernels.ref_first)
    const first = new Int32Array(occ.length);
    let pos = 0, n = 1;
    for (let d = 0; d < levels; d++) {
      let cnt = 0;
      for (let g = pos; g < pos + n; g++) { first[g] = d < levels - 1 ? pos + n + cnt : cnt; cnt += POP[occ[g]]; }
      pos += n; n = cnt;
    }
    return first;
  }
  // within one parent (byte), child k's face neighbours among its siblings: SIB_NB[8 byte + k]
  // the neighbour bits, SIB_UP[3 (8 byte + k) + a] the upper sibling's rank along axis a (-1: none)
  const SIB_NB = new Uint8Array(2048), SIB_UP = new Int8Array(6144).fill(-1);
  for (let byte = 0; byte < 256; byte++) for (let k = 0; k < 8; k++) {
    if (!((byte >> k) & 1)) continue;
    for (let a = 0; a < 3; a++) {
      const bp = 2 - a, kk = k ^ (1 << bp);
      if (!((byte >> kk) & 1)) continue;
      if ((k >> bp) & 1) SIB_NB[8 * byte + k] |= 1 << (2 * a);
      else { SIB_NB[8 * byte + k] |= 1 << (2 * a + 1); SIB_UP[3 * (8 * byte + k) + a] = POP[byte & ((1 << kk) - 1)]; }
    }
  }
  function childNeighbours(pbyte, pstart, pup, n) {
    // face neighbours of the n nodes one depth below parents (bytes pbyte, first children at
    // pstart, upper neighbours pup[a np + p], -1 none; all in Morton order): nb bit 2a = lower
    // neighbour along axis a (x, y, z) exists, bit 2a + 1 = upper; up[a n + q] = the upper
    // neighbours. A child's upper neighbour is its sibling when its own bit a is 0 (SIB_UP),
    // else a child of the parent's upper neighbour, which also gets this child as its lower one.
    const np = pbyte.length, nb = new Uint8Array(n), up = new Int32Array(3 * n).fill(-1);
    let q = 0;
    for (let p = 0; p < np; p++) {
      const byte = pbyte[p], q0 = q;
      for (let bb = byte; bb; bb &= bb - 1, q++) {
        const k = 31 - Math.clz32(bb & -bb), t = 8 * byte + k;
        let bits = SIB_NB[t];
        for (let a = 0; a < 3; a++) {
          const bp = 2 - a;
          if ((k >> bp) & 1) {
            const par = pup[a * np + p];
            if (par < 0) continue;
            const kk = k ^ (1 << bp), pb = pbyte[par];
            if ((pb >> kk) & 1) {
              const j = pstart[par] + POP[pb & ((1 << kk) - 1)];
              up[a * n + q] = j; bits |= 1 << (2 * a + 1); nb[j] |= 1 << (2 * a);
            }
          } else {
            const o = SIB_UP[3 * t + a];
            if (o >= 0) up[a * n + q] = q0 + o;
          }
        }
        nb[q] |= bits;
      }
    }
    return [nb, up];
  }
  function geometryResult(xs, ys, zs, rref, occParts, m, overrun) {
    // [xs, ys, zs, rref, the occupancy bytes of every depth in order] once the leaves are the
    // header's m points and the stream was not read past its end
    if (xs.length !== m || overrun)
      throw new Error("live frame: the geometry stream gives " + xs.length + " points, the header says " + m);
    const occ = new Uint8Array(occParts.reduce((a, o) => a + o.length, 0));
    let o = 0;
    for (const part of occParts) { occ.set(part, o); o += part.length; }
    return [xs, ys, zs, rref, occ];
  }
  function geometry(bytes, levels, m, ref) {
    // the range decoder inlined (one decision site, a small state machine per node): the state in
    // local variables, not an array, is what makes this loop fast. ref: the reference octree of a
    // delta (version 4; NO_REF: none): a node it also has is coded in contexts of its children
    const probs = new Uint16Array(GEO_CONTEXTS).fill(1024), nbytes = bytes.length, rocc = ref.occ, rfirst = ref.first;
    let range = 0xFFFFFFFF, code = 0, pos = 5;
    for (let i = 1; i < 5; i++) code = code * 256 + (i < nbytes ? bytes[i] : 0);  // byte 0: always 0
    let xs = new Uint32Array(1), ys = new Uint32Array(1), zs = new Uint32Array(1), rref = new Int32Array([rocc.length ? 0 : -1]);
    let pbyte = new Uint8Array([1]), pstart = new Int32Array(1), pup = new Int32Array(3).fill(-1);
    const occParts = [];
    for (let d = 0; d < levels; d++) {
      const n = xs.length, [nb, up] = childNeighbours(pbyte, pstart, pup, n), last = d === levels - 1 ? 1 : 0;
      const cap = Math.min(8 * n, m + 8), nx = new Uint32Array(cap), ny = new Uint32Array(cap), nz = new Uint32Array(cap);
      const rnext = new Int32Array(cap), cbyte = new Uint8Array(n), cstart = new Int32Array(n);
      let t = 0;
      for (let i = 0; i < n; i++) {
        const row = last * 64 + nb[i], g = rref[i], rb = g >= 0 ? rocc[g] : 0;
        const rsingle = g >= 0 && (rb & (rb - 1)) === 0, ridx = rsingle ? POP[(rb - 1) & 255] : 0;
        // mode 0: the single-child flag; 1: the single child's index (node of a 3-bit tree); 2: child bit k
        let mode = 0, c = g < 0 ? SINGLE + row : P_SINGLE + (rsingle ? 0 : 128) + row, node = 1, k = 0, byte = 0, match = 1;
        const roff = g < 0 ? 0 : P_CHILD;  // child bit contexts: + 4096 where the reference has the child
        for (;;) {
          const p = probs[c], bound = (range >>> 11) * p;
          let b = 0;
          if (code < bound) { range = bound; probs[c] = p + ((2048 - p) >> 5); }
          else { code -= bound; range -= bound; probs[c] = p - (p >> 5); b = 1; }
          while (range < 16777216) { range *= 256; code = ((code << 8) | (pos < nbytes ? bytes[pos] : 0)) >>> 0; pos++; }
          if (mode === 0) {
            if (b) { mode = 1; c = rsingle ? P_TREE + ((((ridx >> 2) & 1) * 128 + row) << 3) + 1 : TREE + (row << 3) + 1; }
            else { mode = 2; c = BASE[row * 8] + EXTRA[0] + roff + (g < 0 ? 0 : (rb & 1) << 12); }
          } else if (mode === 1) {
            // the single child's index bits, high first; class: the reference's bit while the bits agree, else 2
            if (((ridx >> (node >= 4 ? 0 : node >= 2 ? 1 : 2)) & 1) !== b) match = 0;
            node = 2 * node + b;
            if (node >= 8) { byte = 1 << (node - 8); break; }
            c = !rsingle ? TREE + (row << 3) + node
              : P_TREE + (((match ? (ridx >> (node >= 4 ? 0 : 1)) & 1 : 2) * 128 + row) << 3) + node;
          } else {
            byte |= b << k;
            k++;
            if (k === 7 && POP[byte] <= 1) { byte |= 128; break; }
            if (k === 8) break;
            c = BASE[row * 8 + k] + EXTRA[k * 128 + byte] + roff + (g < 0 ? 0 : ((rb >> k) & 1) << 12);
          }
        }
        cstart[i] = t;
        if (t + POP[byte] > m) throw new Error("live frame: the geometry stream holds more points than the header's " + m);
        const x = 2 * xs[i], y = 2 * ys[i], z = 2 * zs[i];
        for (let q = 0; q < 8; q++)
          if ((byte >> q) & 1) {
            nx[t] = x + (q >> 2); ny[t] = y + ((q >> 1) & 1); nz[t] = z + (q & 1);
            rnext[t] = g >= 0 && (rb >> q) & 1 ? rfirst[g] + POP[rb & ((1 << q) - 1)] : -1;
            t++;
          }
        cbyte[i] = byte;
      }
      occParts.push(cbyte);
      xs = nx.subarray(0, t); ys = ny.subarray(0, t); zs = nz.subarray(0, t); rref = rnext.subarray(0, t);
      pbyte = cbyte; pstart = cstart; pup = up;
    }
    return geometryResult(xs, ys, zs, rref, occParts, m, pos > nbytes);
  }
  // ---- version 7: the geometry as one symbol per node (codec_kernels.decode_geometry_symbols) ----
  // the node's occupancy byte in the canonical frame of its face-neighbour pattern (the cube's 48
  // symmetries, tried in order: axis permutation lexicographic, then flips 0..7; the first giving
  // the smallest pattern wins), from an adaptive frequency table per (last depth, pattern class)
  const SYM_CLASSES = 10, SYM_CONTEXTS = 20, SYM_INC = 32, SYM_LIMIT = 65536, SYM_LAST = [8, 36, 92, 162, 218, 246, 254, 255];
  const [SYM_CLS, SYM_INV] = (() => {
    const perms = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]], moves = [];
    for (const p of perms) for (let f = 0; f < 8; f++) moves.push([p, [(f >> 2) & 1, (f >> 1) & 1, f & 1]]);
    const moveNb = (nb, [p, f]) => {
      let out = 0;
      for (let a = 0; a < 3; a++) for (let side = 0; side < 2; side++) if ((nb >> (2 * a + side)) & 1) out |= 1 << (2 * p[a] + (side ^ f[a]));
      return out;
    };
    const moveK = (k, [p, f]) => { let out = 0; for (let a = 0; a < 3; a++) out |= (((k >> (2 - a)) & 1) ^ f[a]) << (2 - p[a]); return out; };
    const best = [], canon = [];
    for (let nb = 0; nb < 64; nb++) {
      let b = moves[0], c = moveNb(nb, b);
      for (const m of moves) { const v = moveNb(nb, m); if (v < c) { c = v; b = m; } }
      best.push(b); canon.push(c);
    }
    const reps = Array.from(new Set(canon)).sort((x, y) => x - y), cls = new Int32Array(64), inv = new Uint8Array(64 * 256);
    // symbols number the bytes by their number of children, then their value
    const order = Array.from({ length: 255 }, (_, i) => i + 1).sort((x, y) => POP[x] - POP[y] || x - y), rank = new Int32Array(256);
    order.forEach((b, i) => { rank[b] = i + 1; });
    for (let nb = 0; nb < 64; nb++) {
      cls[nb] = reps.indexOf(canon[nb]);
      const kmap = [0, 1, 2, 3, 4, 5, 6, 7].map((k) => moveK(k, best[nb]));
      for (let byte = 0; byte < 256; byte++) {
        let s = 0;
        for (let k = 0; k < 8; k++) if ((byte >> k) & 1) s |= 1 << kmap[k];
        inv[nb * 256 + rank[s]] = byte;
      }
    }
    return [cls, inv];
  })();
  function geometrySymbols(bytes, levels, m) {
    // the symbol of a byte of c children starts at count max(1, 16 >> (c - 1)), the empty byte at 0
    const freq = new Int32Array(SYM_CONTEXTS * 256), blk = new Int32Array(SYM_CONTEXTS * 16);
    const total = new Int32Array(SYM_CONTEXTS), nbytes = bytes.length;
    for (let s = 1, children = 1; s < 256; s++) {
      while (s > SYM_LAST[children - 1]) children++;
      const f = Math.max(1, 16 >> (children - 1));
      for (let c = 0; c < SYM_CONTEXTS; c++) { freq[c * 256 + s] = f; blk[c * 16 + (s >> 4)] += f; total[c] += f; }
    }
    let range = 0xFFFFFFFF, code = 0, pos = 5;
    for (let i = 1; i < 5; i++) code = code * 256 + (i < nbytes ? bytes[i] : 0);  // byte 0: always 0
    let xs = new Uint32Array(1), ys = new Uint32Array(1), zs = new Uint32Array(1);
    let pbyte = new Uint8Array([1]), pstart = new Int32Array(1), pup = new Int32Array(3).fill(-1);
    const occParts = [];
    for (let d = 0; d < levels; d++) {
      const n = xs.length, [nb, up] = childNeighbours(pbyte, pstart, pup, n), last = d === levels - 1 ? SYM_CLASSES : 0;
      const cap = Math.min(8 * n, m + 8), nx = new Uint32Array(cap), ny = new Uint32Array(cap), nz = new Uint32Array(cap);
      const cbyte = new Uint8Array(n), cstart = new Int32Array(n);
      let t = 0;
      for (let i = 0; i < n; i++) {
        const c = last + SYM_CLS[nb[i]], f0 = c * 256, b0 = c * 16, tot = total[c];
        const r = Math.floor(range / tot), v = Math.floor(code / r);
        if (v >= tot) throw new Error("live frame: the geometry stream is corrupt");
        let cum = 0, b = 0;
        while (cum + blk[b0 + b] <= v) cum += blk[b0 + b++];
        let s = b << 4;
        while (cum + freq[f0 + s] <= v) cum += freq[f0 + s++];
        code -= r * cum; range = r * freq[f0 + s];
        freq[f0 + s] += SYM_INC; blk[b0 + (s >> 4)] += SYM_INC; total[c] = tot + SYM_INC;
        if (tot + SYM_INC > SYM_LIMIT) {
          let sum = 0;
          blk.fill(0, b0, b0 + 16);
          for (let q = 1; q < 256; q++) { const h = (freq[f0 + q] + 1) >> 1; freq[f0 + q] = h; blk[b0 + (q >> 4)] += h; sum += h; }
          total[c] = sum;
        }
        while (range < 16777216) { range *= 256; code = ((code << 8) | (pos < nbytes ? bytes[pos] : 0)) >>> 0; pos++; }
        const byte = SYM_INV[nb[i] * 256 + s];
        cstart[i] = t;
        if (t + POP[byte] > m) throw new Error("live frame: the geometry stream holds more points than the header's " + m);
        const x = 2 * xs[i], y = 2 * ys[i], z = 2 * zs[i];
        for (let bb = byte; bb; bb &= bb - 1, t++) {
          const q = 31 - Math.clz32(bb & -bb);
          nx[t] = x + (q >> 2); ny[t] = y + ((q >> 1) & 1); nz[t] = z + (q & 1);
        }
        cbyte[i] = byte;
      }
      occParts.push(cbyte);
      xs = nx.subarray(0, t); ys = ny.subarray(0, t); zs = nz.subarray(0, t);
      pbyte = cbyte; pstart = cstart; pup = up;
    }
    return geometryResult(xs, ys, zs, new Int32Array(m).fill(-1), occParts, m, pos > nbytes);
  }
  const size = (r) => (r === 0 ? 0 : r === 1 || r === -1 ? 1 : 2);
  function colours(bytes, m, ls, cs, blk, rleaf, rq, adaptive) {
    // a point with a reference point (rleaf[i] >= 0; rq: the reference's quantised Y, Co, Cg,
    // 3 per point) predicts from it, in contexts of its own; adaptive (versions 5 and 6): a block
    // starts with its split flag, and every point of a split block has its own chroma; returns
    // [rgb, this frame's q]. The range decoder is inlined (its state in local variables, one
    // decision site): per point up to four tasks (luma, split flag, Co, Cg), each a small state
    // machine over residual()'s decisions
    const P = new Uint16Array(COL_CONTEXTS).fill(1024), nbytes = bytes.length;
    const rgb = new Uint8ClampedArray(3 * m), q = new Int32Array(3 * m);  // clamps, and rounds half to even as numpy's rint
    let range = 0xFFFFFFFF, code = 0, pos = 5;
    for (let i = 1; i < 5; i++) code = code * 256 + (i < nbytes ? bytes[i] : 0);  // byte 0: always 0
    let py = 0, pco = 0, pcg = 0, sy = 0, sco = 0, scg = 0, sry = 0, src = 0, split = 0, r1 = 0, s1 = 0;
    for (let i = 0; i < m; i++) {
      const j = rleaf ? rleaf[i] : -1, first = i % blk === 0;
      for (let task = 0; task < 4; task++) {
        let base;
        if (task === 0) base = j >= 0 ? (21 + sry) * RES : sy * RES;
        else if (task === 1) { if (!(first && adaptive)) continue; base = SPLIT + split; }
        else if (!(first || split)) break;
        else if (task === 2) base = j >= 0 ? (24 + src) * RES : (3 + sco * 3 + sy) * RES;
        else base = j >= 0 ? (27 + s1) * RES : (12 + scg * 3 + s1) * RES;
        // phase 0: nonzero flag, 1: sign, 2: unary magnitude, 3: Exp-Golomb prefix, 4: its suffix, 5: a split flag
        let c = base, phase = task === 1 ? 5 : 0, a = 0, neg = 0, n = 0, e = 1, r = 0;
        for (;;) {
          const p = P[c], bound = (range >>> 11) * p;
          let b = 0;
          if (code < bound) { range = bound; P[c] = p + ((2048 - p) >> 5); }
          else { code -= bound; range -= bound; P[c] = p - (p >> 5); b = 1; }
          while (range < 16777216) { range *= 256; code = ((code << 8) | (pos < nbytes ? bytes[pos] : 0)) >>> 0; pos++; }
          if (phase === 2) {
            if (!b) { r = neg ? -a : a; break; }
            if (++a < ESCAPE) c = base + 1 + a;
            else { phase = 3; c = base + 15; }
          } else if (phase === 0) {
            if (!b) break;
            phase = 1; c = base + 1;
          } else if (phase === 1) { neg = b; a = 1; phase = 2; c = base + 2; }
          else if (phase === 5) { split = b; break; }
          else if (phase === 3) {
            if (b) {
              if (++n > MAX_PREFIX) throw new Error("live frame: the colour stream is corrupt");
              c = base + 15 + Math.min(n, 8);
            } else if (n === 0) { r = neg ? -ESCAPE : ESCAPE; break; }
            else { phase = 4; n--; c = base + 24 + Math.min(n, 7); }
          } else {
            e = (e << 1) | b;
            if (--n < 0) { r = neg ? -(e + ESCAPE - 1) : e + ESCAPE - 1; break; }
            c = base + 24 + Math.min(n, 7);
          }
        }
        if (task === 0) {
          if (j >= 0) { sry = size(r); py = rq[3 * j] + r; } else { sy = size(r); py += r; }
        } else if (task === 2) { r1 = r; s1 = size(r); }
        else if (task === 3) {
          if (j >= 0) { src = Math.max(s1, size(r)); pco = rq[3 * j + 1] + r1; pcg = rq[3 * j + 2] + r; }
          else { sco = s1; scg = size(r); pco += r1; pcg += r; }
        }
      }
      q[3 * i] = py; q[3 * i + 1] = pco; q[3 * i + 2] = pcg;
      const Y = py * ls, Co = pco * cs, Cg = pcg * cs;
      rgb[3 * i] = (Y + Co * 0.5) - Cg * 0.5; rgb[3 * i + 1] = Y + Cg * 0.5; rgb[3 * i + 2] = (Y - Co * 0.5) - Cg * 0.5;
    }
    if (pos > nbytes) throw new Error("live frame: the colour stream ends early");
    return [rgb, q];
  }
  const gridOf = (buf) => Array.from(new Uint8Array(buf, 20, 16)).concat(Array.from(new Uint8Array(buf, 44, 4))).join(",");
  function keyGeometry(version, bytes, levels, m, origin, step) {
    // a key frame's geometry stream (version 3, 5 or 7) -> {xyz, occ, first}: the points, the
    // octree's bytes and refFirst of them (what a delta after it refers to); needs nothing of the
    // colour stream, so it can run beside colours() (in a Worker: decode-worker.js)
    const [xs, ys, zs, , occ] = version === 7 ? geometrySymbols(bytes, levels, m) : geometry(bytes, levels, m, NO_REF);
    return { xyz: cellCentres(xs, ys, zs, m, origin, step), occ, first: refFirst(occ, levels) };
  }
  function cellCentres(xs, ys, zs, m, origin, step) {
    const xyz = new Float32Array(3 * m);
    for (let i = 0; i < m; i++) {
      xyz[3 * i] = origin[0] + (xs[i] + 0.5) * step;
      xyz[3 * i + 1] = origin[1] + (ys[i] + 0.5) * step;
      xyz[3 * i + 2] = origin[2] + (zs[i] + 0.5) * step;
    }
    return xyz;
  }
  function decodeV3(buf, dv, holder, offload) {
    // version 3 (a key frame) or 4 (a delta against the frame holder.ref holds); holder.ref
    // becomes this frame. offload (optional): (job) -> Promise of keyGeometry's result, computed
    // elsewhere (a Worker) while this thread decodes the colour stream; taken for key frames only
    // (a delta's colours need its geometry's reference points); returns then a Promise
    const version = dv.getUint16(4, true), delta = version === 4 || version === 6, H = delta ? 64 : 60;
    if (buf.byteLength < H || dv.getUint16(6, true) !== H) throw new Error("live frame: bad version-" + version + " header");
    const m = dv.getUint32(12, true), pointsIn = dv.getUint32(16, true);
    const origin = [f32(dv, 20), f32(dv, 24), f32(dv, 28)], step = f32(dv, 32);
    const levels = dv.getUint8(44), ls = dv.getUint8(45), cs = dv.getUint8(46), blk = dv.getUint8(47);
    const s1 = dv.getUint32(52, true), s2 = dv.getUint32(56, true);
    if (buf.byteLength !== H + s1 + s2) throw new Error("live frame: " + buf.byteLength + " bytes, the header says " + (H + s1 + s2));
    if (levels < 1 || levels > 21 || !(step > 0) || m > pointsIn || pointsIn > (1 << 26) || !ls || !cs || !blk)
      throw new Error("live frame: bad version-" + version + " header");
    if (crc32(new Uint8Array(buf, H)) !== dv.getUint32(48, true)) throw new Error("live frame: the checksum does not match");
    let ref = NO_REF;
    if (delta) {
      const want = dv.getUint32(60, true), held = holder && holder.ref;
      if (!held || held.number !== want || held.grid !== gridOf(buf))
        throw new Error("live frame: a delta against frame " + want + ", but this decoder holds " + (held ? "frame " + held.number : "no frame"));
      ref = held;
    }
    if (holder) holder.ref = null;  // a frame that fails to decode leaves nothing to refer to
    const frame = { m, pointsIn, xyz: new Float32Array(0), rgb: new Uint8ClampedArray(0), latency: f32(dv, 36), fuseMs: f32(dv, 40) };
    if (m === 0) {
      if (s1 + s2) throw new Error("live frame: streams given for a frame of no points");
      return frame;
    }
    const held = (occ, first, q) => { if (holder) holder.ref = { number: dv.getUint32(8, true), grid: gridOf(buf), occ, first, q }; };
    const colourBytes = new Uint8Array(buf, H + s1, s2);
    if (offload && !delta) {
      // the worker gets a copy of the geometry stream (the caller's buffer stays whole) and
      // transfers back what it made; this thread decodes the colours meanwhile
      const pending = offload({ version, geo: buf.slice(H, H + s1), levels, m, origin, step });
      const [rgb, q] = colours(colourBytes, m, ls, cs, blk, null, NO_REF.q, version >= 5);
      return pending.then((g) => {
        held(g.occ, g.first, q);
        return Object.assign(frame, { xyz: g.xyz, rgb, split: true });
      });
    }
    const geo = new Uint8Array(buf, H, s1);
    const [xs, ys, zs, rleaf, occ] = version === 7 ? geometrySymbols(geo, levels, m) : geometry(geo, levels, m, ref);
    frame.xyz = cellCentres(xs, ys, zs, m, origin, step);
    const [rgb, q] = colours(colourBytes, m, ls, cs, blk, ref === NO_REF ? null : rleaf, ref.q, version >= 5);
    frame.rgb = rgb;
    if (holder) held(occ, refFirst(occ, levels), q);
    return frame;
  }
  async function decode(buf, holder, offload) {
    if (buf.byteLength < 8) throw new Error("frame shorter than a header");
    const dv = new DataView(buf);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    const version = magic === "FFLV" ? dv.getUint16(4, true) : 0;
    let frame;
    if (version === 1) frame = decodeRaw(buf, dv);
    else if (version >= 3 && version <= 7) frame = await decodeV3(buf, dv, holder, offload);
    else if (version === 2) { if (holder) holder.ref = null; frame = await decodeCompact(buf, dv); }
    else throw new Error("unknown frame format");
    return Object.assign(frame, { version, number: dv.getUint32(8, true) });
  }
  // one message on its own (a delta, version 4 or 6, is refused: it needs the frame before it)
  const decodeFrame = (buf) => decode(buf, null);
  let jobs = 0;  // job ids, unique over every decoder (decoders may share a worker)
  function workerOffload(worker) {
    // () -> (job) -> Promise of keyGeometry's result, computed by worker (running decode-worker.js);
    // null once the worker failed (the decoder then decodes on its own thread)
    const waiting = new Map();
    let broken = false;
    const fail = (why) => {
      broken = true;
      for (const w of waiting.values()) w.reject(new Error(why));
      waiting.clear();
    };
    worker.addEventListener("message", (e) => {
      const w = waiting.get(e.data.id);
      if (!w) return;
      waiting.delete(e.data.id);
      if (e.data.error) w.reject(new Error(e.data.error));
      else w.resolve(e.data);
    });
    worker.addEventListener("error", (e) => { e.preventDefault(); fail("the decode worker failed: " + (e.message || "no script")); });
    worker.addEventListener("messageerror", () => fail("the decode worker sent an unreadable message"));
    const run = (job) => new Promise((resolve, reject) => {
      const id = jobs++;
      waiting.set(id, { resolve, reject });
      worker.postMessage({ id, ...job }, [job.geo]);
    });
    return () => (broken ? null : run);
  }
  // the messages of one stream in order: holds the last compact frame for the delta after it.
  // options.worker (optional): a Worker running decode-worker.js; a key frame's geometry is then
  // decoded there while this thread decodes its colours (the same points and colours; the frame
  // has split: true); a delta, and every frame after the worker failed, decode on this thread.
  // Calls are queued: each decodes after the one before it settled.
  function createDecoder(options) {
    const holder = { ref: null }, offload = options && options.worker ? workerOffload(options.worker) : () => null;
    let queue = Promise.resolve(), split = 0;
    const one = async (buf) => {
      const run = offload();
      if (!run) return decode(buf, holder);
      try {
        const f = await decode(buf, holder, run);
        if (f.split) split++;
        return f;
      } catch (err) {
        if (offload()) throw err;  // the frame's fault, not the worker's
        return decode(buf, holder);  // the worker died meanwhile: this thread alone
      }
    };
    return {
      decodeFrame: (buf) => { const p = queue.then(() => one(buf)); queue = p.catch(() => {}); return p; },
      held: () => (holder.ref ? holder.ref.number : null),
      split: () => split,  // frames decoded across the worker
    };
  }
  const api = { decodeFrame, createDecoder, keyGeometry };
  if (typeof module !== "undefined" && module.exports) module.exports = api;
  else root.FuseFlowDecode = api;
})(typeof self !== "undefined" ? self : globalThis);
