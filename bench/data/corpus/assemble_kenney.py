"""Assemble a single-file glTF (GLB) scene from Kenney kit pieces (CC0).

Not used by tests: it records how kenney_suburb.glb and kenney_retro_urban.glb were
made. Pieces come from the Kenney "City Kit Suburban 2.0" + "City Kit Roads" and
"Retro Urban Kit 2.0" GLBs, as copied in github.com/atomical/afps at commit
b4124391395e96016bce5b81c5d51fe22c46420e (client/public/assets/environments/cc0/).
The layout (which piece where) is this corpus's own, written below.

Each piece's triangles (positions, normals, TEXCOORD_0) are transformed to world space
(node transforms of the piece, then the placement, then a uniform scale), grouped by
the piece's material, and written as one mesh with one primitive per material; each
material keeps its baseColorTexture (the kit's PNG, embedded unchanged) and sampler.
KHR_texture_transform (identity in these kits) and KHR_materials_unlit are dropped.
Scale: x8 for the suburb (a house about 10 m wide), x4 for retro urban (a 4 m storey).
Usage: python assemble_kenney.py KIT_DIR suburb|retro OUT.glb
"""
import json, struct, sys
from pathlib import Path
import numpy as np

def read_glb(path):
    b = Path(path).read_bytes()
    n = struct.unpack('<I', b[12:16])[0]
    j = json.loads(b[20:20 + n])
    off = 20 + n
    m = struct.unpack('<I', b[off:off + 4])[0]
    return j, b[off + 8: off + 8 + m]

CT = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
NC = {'SCALAR': 1, 'VEC2': 2, 'VEC3': 3, 'VEC4': 4}

def acc(j, bin_, i):
    a = j['accessors'][i]; v = j['bufferViews'][a['bufferView']]
    dt = np.dtype(CT[a['componentType']]); nc = NC[a['type']]
    start = v.get('byteOffset', 0) + a.get('byteOffset', 0)
    stride = v.get('byteStride', dt.itemsize * nc)
    raw = np.frombuffer(bin_, np.uint8, count=stride * (a['count'] - 1) + dt.itemsize * nc, offset=start)
    out = np.lib.stride_tricks.as_strided(raw, (a['count'], dt.itemsize * nc), (stride, 1)).copy()
    return out.view(dt).reshape(a['count'], nc)

def node_mat(n):
    if 'matrix' in n: return np.array(n['matrix'], float).reshape(4, 4).T
    T = np.eye(4); T[:3, 3] = n.get('translation', [0, 0, 0])
    x, y, z, w = n.get('rotation', [0, 0, 0, 1])
    R = np.eye(4); R[:3, :3] = [[1-2*(y*y+z*z), 2*(x*y-z*w), 2*(x*z+y*w)],
                                [2*(x*y+z*w), 1-2*(x*x+z*z), 2*(y*z-x*w)],
                                [2*(x*z-y*w), 2*(y*z+x*w), 1-2*(x*x+y*y)]]
    S = np.diag(list(n.get('scale', [1, 1, 1])) + [1])
    return T @ R @ S

def piece_tris(path):
    """-> {material name: (P, N, UV, image path, sampler)} in the piece's frame."""
    j, bin_ = read_glb(path)
    out = {}
    def walk(ni, M):
        n = j['nodes'][ni]; M = M @ node_mat(n)
        if 'mesh' in n:
            for p in j['meshes'][n['mesh']]['primitives']:
                assert p.get('mode', 4) == 4
                P = acc(j, bin_, p['attributes']['POSITION']).astype(float)
                N = acc(j, bin_, p['attributes']['NORMAL']).astype(float)
                UV = acc(j, bin_, p['attributes']['TEXCOORD_0']).astype(float)
                idx = acc(j, bin_, p['indices']).ravel() if 'indices' in p else np.arange(len(P))
                P = (np.c_[P, np.ones(len(P))] @ M.T)[:, :3]
                N = N @ np.linalg.inv(M[:3, :3])
                N /= np.linalg.norm(N, axis=1, keepdims=True)
                mat = j['materials'][p['material']]
                t = j['textures'][mat['pbrMetallicRoughness']['baseColorTexture']['index']]
                img = Path(path).parent / j['images'][t['source']]['uri']
                smp = j['samplers'][t['sampler']] if 'sampler' in t else {}
                assert mat['pbrMetallicRoughness'].get('baseColorFactor', [1, 1, 1, 1]) == [1, 1, 1, 1]
                out.setdefault(mat['name'], []).append((P[idx], N[idx], UV[idx], img, smp))
        for c in n.get('children', []): walk(c, M)
    for r in j['scenes'][j.get('scene', 0)]['nodes']: walk(r, np.eye(4))
    return out

def place(xz, yaw_deg=0.0, y=0.0):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    M = np.eye(4); M[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]; M[:3, 3] = [xz[0], y, xz[1]]
    return M

def layout_suburb():
    L = []
    R = 4  # tiles -4..4 in x and z; roads along x = 0 and z = 0
    for i in range(-R, R + 1):
        for k in range(-R, R + 1):
            if i == 0 and k == 0: L.append(('roads/road-crossroad.glb', (i, k), 0))
            elif i == 0: L.append(('roads/road-straight.glb', (i, k), 0))
            elif k == 0: L.append(('roads/road-straight.glb', (i, k), 90))
            else: L.append(('roads/tile-low.glb', (i, k), 0))
    houses = 'abcdefghijklmnopqrstu'
    h = 0
    for sx in (-1, 1):
        for sz in (-1, 1):
            for a in (1.5, 3.2):
                for b in (1.5, 3.2):
                    yaw = 0 if sz > 0 else 180
                    L.append((f'building-type-{houses[h % 21]}.glb', (sx * a, sz * b), yaw)); h += 1
            L.append(('tree-large.glb', (sx * 2.35, sz * 3.9), 0))
            L.append(('tree-small.glb', (sx * 3.9, sz * 2.35), 0))
    return L

def layout_retro():
    L = []
    # ground: 2x2 road tiles along z = 0, grass elsewhere (grass tiles are 1x1)
    for i in range(-3, 3):
        L.append(('road-asphalt-straight.glb', (i * 2 + 1, 0), 90))
    for i in range(-6, 6):
        for k in list(range(-6, -1)) + list(range(1, 6)):
            L.append(('grass.glb', (i + 0.5, k + 0.5), 0))
    # two small buildings built from 1x1x1 wall modules: 3x2 footprint, 2 storeys
    for (ox, oz, face) in ((-3.5, -3.0, 0), (2.5, 3.0, 180)):
        for st in range(2):
            for dx in range(3):
                for dz in range(2):
                    name = 'wall-a-window.glb' if (st == 1 or dx != 1) else 'wall-a-door.glb'
                    if dz == 1: name = 'wall-a-flat.glb'
                    L.append((name, (ox + dx, oz + (dz if face == 0 else -dz)), face, st * 1.0))
        for dx in range(3):
            for dz in range(2):
                L.append(('wall-a-roof.glb', (ox + dx, oz + (dz if face == 0 else -dz)), face, 2.0))
    L += [('tree-large.glb', (-5.0, 3.5), 0), ('tree-pine-large.glb', (4.5, -3.5), 0),
          ('tree-park-large.glb', (0.5, -4.0), 0), ('truck-green.glb', (-1.0, 0.5), 90),
          ('detail-bench.glb', (0.0, 2.0), 180), ('detail-dumpster-closed.glb', (-1.5, -2.0), 0)]
    return [x for x in L if x is not None]

def build(kit, which, out, scale=8.0):
    kit = Path(kit); glb = kit / 'glb'
    L = layout_suburb() if which == 'suburb' else layout_retro()
    groups, images, samplers = {}, {}, {}
    cache = {}
    for item in L:
        f, xz, yaw = item[:3]; y = item[3] if len(item) > 3 else 0.0
        if f not in cache: cache[f] = piece_tris(glb / f)
        M = np.diag([scale, scale, scale, 1.0]) @ place(xz, yaw, y)
        for name, parts in cache[f].items():
            for P, N, UV, img, smp in parts:
                Pw = (np.c_[P, np.ones(len(P))] @ M.T)[:, :3]
                Nw = N @ M[:3, :3].T; Nw /= np.linalg.norm(Nw, axis=1, keepdims=True)
                groups.setdefault(name, []).append((Pw, Nw, UV))
                images[name] = img; samplers[name] = smp
    names = sorted(groups)
    blob = bytearray(); views = []; accs = []; prims = []; mats = []; texs = []; imgs = []; smps = []
    def add(arr, target=None, minmax=False, typ='VEC3', ct=5126):
        nonlocal blob
        while len(blob) % 4: blob += b'\0'
        data = np.ascontiguousarray(arr).tobytes()
        v = {'buffer': 0, 'byteOffset': len(blob), 'byteLength': len(data)}
        if target: v['target'] = target
        views.append(v); blob += data
        a = {'bufferView': len(views) - 1, 'componentType': ct, 'count': len(arr), 'type': typ}
        if minmax: a['min'] = arr.min(0).tolist(); a['max'] = arr.max(0).tolist()
        accs.append(a); return len(accs) - 1
    img_index = {}
    for mi, name in enumerate(names):
        P = np.concatenate([g[0] for g in groups[name]]).astype(np.float32)
        N = np.concatenate([g[1] for g in groups[name]]).astype(np.float32)
        UV = np.concatenate([g[2] for g in groups[name]]).astype(np.float32)
        # de-duplicate vertices for an indexed primitive
        key = np.c_[P, N, UV]
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        idx = inv.ravel().astype(np.uint32)
        prims.append({'attributes': {'POSITION': add(uniq[:, :3].copy(), 34962, True),
                                     'NORMAL': add(uniq[:, 3:6].copy(), 34962),
                                     'TEXCOORD_0': add(uniq[:, 6:8].copy(), 34962, typ='VEC2')},
                      'indices': add(idx, 34963, typ='SCALAR', ct=5125), 'material': mi, 'mode': 4})
        ip = images[name]
        if ip not in img_index:
            data = Path(ip).read_bytes()
            while len(blob) % 4: blob += b'\0'
            views.append({'buffer': 0, 'byteOffset': len(blob), 'byteLength': len(data)}); blob += data
            imgs.append({'bufferView': len(views) - 1, 'mimeType': 'image/png', 'name': Path(ip).stem})
            img_index[ip] = len(imgs) - 1
        smps.append(samplers[name])
        texs.append({'source': img_index[ip], 'sampler': len(smps) - 1})
        mats.append({'name': name, 'pbrMetallicRoughness': {'baseColorTexture': {'index': len(texs) - 1},
                     'metallicFactor': 0.0, 'roughnessFactor': 1.0}})
    while len(blob) % 4: blob += b'\0'
    j = {'asset': {'version': '2.0', 'generator': 'pydynrad bench/data/corpus/assemble_kenney.py',
                   'copyright': 'Kenney (www.kenney.nl), CC0 1.0'},
         'scene': 0, 'scenes': [{'nodes': [0]}], 'nodes': [{'mesh': 0, 'name': f'kenney_{which}'}],
         'meshes': [{'name': f'kenney_{which}', 'primitives': prims}], 'materials': mats,
         'textures': texs, 'images': imgs, 'samplers': smps, 'accessors': accs,
         'bufferViews': views, 'buffers': [{'byteLength': len(blob)}]}
    js = json.dumps(j, separators=(',', ':')).encode()
    while len(js) % 4: js += b' '
    total = 12 + 8 + len(js) + 8 + len(blob)
    Path(out).write_bytes(struct.pack('<III', 0x46546C67, 2, total) + struct.pack('<II', len(js), 0x4E4F534A) + js
                          + struct.pack('<II', len(blob), 0x004E4942) + bytes(blob))

if __name__ == '__main__':
    build(sys.argv[1], sys.argv[2], sys.argv[3], scale=8.0 if sys.argv[2] == 'suburb' else 4.0)
