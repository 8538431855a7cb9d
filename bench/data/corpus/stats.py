"""Recompute corpus.json's counts and texture statistics, independently of pydynrad.

OBJ: counts parsed by hand (`v ` lines; `f ` lines, an n-gon counted as n - 2 triangles;
materials from `usemtl`; Kd / Ke / map_Kd from the MTL). GLB: counts from the glTF JSON
(POSITION accessor counts, index accessor count / 3). Texture means: the image decoded with
OpenImageIO, mean over pixels of the 8-bit values / 255 ("srgb") and of their
IEC 61966-2-1 decoding ("linear"), per RGB channel (alpha ignored).
"""
import json, struct
from pathlib import Path
import numpy as np
import OpenImageIO as oiio

def srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)

def image_stats(path=None, data=None):
    if data is not None:
        tmp = Path('/tmp/_corpus_img.png'); tmp.write_bytes(data); path = tmp
    cfg = oiio.ImageSpec(); cfg.attribute('oiio:UnassociatedAlpha', 1)  # no premultiplication
    buf = oiio.ImageBuf(str(path), 0, 0, cfg)
    px = buf.get_pixels(oiio.FLOAT)  # normalised 8-bit values, no colour conversion
    rgb = px[..., :3].reshape(-1, 3).astype(np.float64)
    if rgb.shape[1] < 3: rgb = np.repeat(rgb[:, :1], 3, axis=1)
    return {'size': [buf.spec().width, buf.spec().height], 'channels': buf.spec().nchannels,
            'mean_srgb': [round(float(x), 5) for x in rgb.mean(0)],
            'mean_linear': [round(float(x), 5) for x in srgb_to_linear(rgb).mean(0)]}

def obj_stats(obj):
    obj = Path(obj); nv = nt = 0; per = {}; cur = None; mtllib = None
    for ln in obj.read_text().splitlines():
        t = ln.split()
        if not t: continue
        if t[0] == 'v': nv += 1
        elif t[0] == 'f': nt += len(t) - 3; per[cur] = per.get(cur, 0) + len(t) - 3
        elif t[0] == 'usemtl': cur = t[1]
        elif t[0] == 'mtllib': mtllib = t[1]
    mats = {}; m = None
    for ln in (obj.parent / mtllib).read_text().splitlines():
        t = ln.split('#')[0].split()
        if not t: continue
        if t[0] == 'newmtl': m = t[1]; mats[m] = {}
        elif t[0] in ('Kd', 'Ke'): mats[m][t[0]] = [float(x) for x in t[1:4]]
        elif t[0] == 'map_Kd':
            mats[m]['map_Kd'] = t[-1]; mats[m]['texture'] = image_stats(obj.parent / t[-1])
    for k in mats: mats[k]['triangles'] = per.get(k, 0)
    return nv, nt, mats

def glb_stats(glb):
    b = Path(glb).read_bytes(); n = struct.unpack('<I', b[12:16])[0]
    j = json.loads(b[20:20 + n]); binc = b[20 + n + 8:]
    nv = nt = 0; per = {}
    for m in j['meshes']:
        for p in m['primitives']:
            c = j['accessors'][p['attributes']['POSITION']]['count']
            t = j['accessors'][p['indices']]['count'] // 3
            nv += c; nt += t; per[p['material']] = per.get(p['material'], 0) + t
    mats = {}
    for i, m in enumerate(j['materials']):
        pbr = m.get('pbrMetallicRoughness', {})
        d = {'baseColorFactor': pbr.get('baseColorFactor', [1, 1, 1, 1]), 'triangles': per.get(i, 0)}
        if 'emissiveFactor' in m: d['emissiveFactor'] = m['emissiveFactor']
        if 'baseColorTexture' in pbr:
            tex = j['textures'][pbr['baseColorTexture']['index']]; im = j['images'][tex['source']]
            v = j['bufferViews'][im['bufferView']]
            data = binc[v.get('byteOffset', 0): v.get('byteOffset', 0) + v['byteLength']]
            d['baseColorTexture'] = f"embedded image {tex['source']} ({im.get('name')})"
            d['sampler'] = j['samplers'][tex['sampler']] if 'sampler' in tex else {}
            d['texture'] = image_stats(data=data)
        mats[m['name']] = d
    return nv, nt, mats

if __name__ == '__main__':
    here = Path(__file__).parent
    for f in ['cornell_box/CornellBox-Original.obj', 'veach_ajar/veach_ajar.obj']:
        print(f, json.dumps(obj_stats(here / f))[:3000])
    for f in ['kenney_suburb/kenney_suburb.glb', 'kenney_retro_urban/kenney_retro_urban.glb']:
        print(f, json.dumps(glb_stats(here / f))[:3000])
