// Reader of the packed scene files the API serves (vpp_core/report/scene.py: `pack`).
const TYPES = { float32: Float32Array, uint32: Uint32Array, uint8: Uint8Array };

/** {meta, arrays}: the JSON header and zero-copy typed arrays of a packed scene file. */
export function unpack(buffer) {
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, 4));
  if (magic !== 'VPPS') throw new Error('not a vpp scene file');
  const length = new DataView(buffer).getUint32(4, true);
  const meta = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 8, length)));
  const arrays = {};
  for (const [name, rec] of Object.entries(meta.arrays)) {
    const count = rec.shape.reduce((a, b) => a * b, 1);
    arrays[name] = new TYPES[rec.dtype](buffer, rec.offset, count);
  }
  delete meta.arrays;
  return { meta, arrays };
}
