"""Convert Bitterli's Mitsuba 'Veach, Ajar' (CC0) to one OBJ + MTL. Not used by tests.

Source: github.com/chellmuth/pathed @ 865b7c5f62757b642c075e604135cd2cfd71f582,
scenes/veach-ajar/ (scene.xml, models/*.obj, textures/*.jpg). Mesh000.obj and Mesh009.obj
(the two teapots on the table: Pot2/Pot3/Material shapes) are over the snapshot's 4 MiB file
limit and are omitted. Every other shape is written with its scene.xml transform applied
(vertices and normals transformed where it is not the identity) as a group `g MeshNNN` with `usemtl <bsdf id>`; the rectangle emitter becomes
two triangles with Ke = its radiance. Usage: python convert_veach_ajar.py SRC_DIR OUT_DIR
"""
import re, sys, shutil, subprocess
from pathlib import Path
import numpy as np
import xml.etree.ElementTree as ET

src, out = Path(sys.argv[1]), Path(sys.argv[2])
out.mkdir(parents=True, exist_ok=True)
root = ET.parse(src / 'scene.xml').getroot()
shapes = []
for s in root.findall('shape'):
    m = s.find('transform/matrix')
    M = np.array([float(x) for x in m.get('value').split()]).reshape(4, 4)
    ref = s.find('ref').get('id')
    if s.get('type') == 'obj':
        shapes.append(('obj', s.find('string').get('value'), M, ref))
    else:
        shapes.append(('rectangle', s.find('emitter/rgb').get('value'), M, ref))
lines = ['# "Veach, Ajar" by Benedikt Bitterli (CC0), converted from the Mitsuba scene; see LICENSES.md',
         'mtllib veach_ajar.mtl']
nv = nvt = nvn = 0
for kind, what, M, ref in shapes:
    if kind == 'obj':
        f = src / what
        if not f.exists():
            print('omitted (absent from source snapshot):', what, ref); continue
        V, VT, VN, F = [], [], [], []
        for ln in f.read_text().splitlines():
            t = ln.split()
            if not t: continue
            if t[0] == 'v':
                x = M @ np.array([float(t[1]), float(t[2]), float(t[3]), 1.0])
                V.append(ln if np.allclose(M, np.eye(4)) else 'v %.6f %.6f %.6f' % tuple(x[:3]))
            elif t[0] == 'vt': VT.append(ln)
            elif t[0] == 'vn':
                n = np.linalg.inv(M[:3, :3]).T @ np.array([float(t[1]), float(t[2]), float(t[3])])
                n /= np.linalg.norm(n)
                VN.append(ln if np.allclose(M, np.eye(4)) else 'vn %.6f %.6f %.6f' % tuple(n))
            elif t[0] == 'f':
                F.append(t[1:])
        lines.append(f'g {Path(what).stem}'); lines.append(f'usemtl {ref}')
        lines += V + VT + VN
        for face in F:
            o = []
            for c in face:
                p = c.split('/')
                q = [str(int(p[0]) + nv)]
                if len(p) > 1: q.append(str(int(p[1]) + nvt) if p[1] else '')
                if len(p) > 2: q.append(str(int(p[2]) + nvn) if p[2] else '')
                o.append('/'.join(q))
            lines.append('f ' + ' '.join(o))
        nv += len(V); nvt += len(VT); nvn += len(VN)
    else:
        # Mitsuba rectangle: [-1,1]^2 in z = 0, normal +z, emits on the +normal side
        C = np.array([[-1, -1, 0, 1], [1, -1, 0, 1], [1, 1, 0, 1], [-1, 1, 0, 1]]) @ M.T
        lines.append('g Light'); lines.append('usemtl Light')
        lines += ['v %.6f %.6f %.6f' % tuple(c[:3]) for c in C]
        lines += [f'f {nv+1} {nv+2} {nv+3}', f'f {nv+1} {nv+3} {nv+4}']
        nv += 4
(out / 'veach_ajar.obj').write_text('\n'.join(lines) + '\n')
mtl = """# Materials of "Veach, Ajar" (Bitterli, CC0), from scene.xml. Diffuse reflectances as given;
# non-diffuse BSDFs approximated for a diffuse solver (see LICENSES.md, 'what we changed').
newmtl Landscape
Kd 1 1 1
map_Kd textures/landscape.jpg

newmtl Table
Kd 1 1 1
map_Kd textures/table.jpg

newmtl Door
Kd 1 1 1
map_Kd textures/door.jpg

newmtl Diffuse
Kd 0.8 0.8 0.8

newmtl DoorFrame
Kd 0.247059 0.168627 0.0901961

newmtl PictureFrame
Kd 0.258824 0.207843 0.145098

# roughconductor with a checkerboard specularReflectance (0.2 / 0.8): area mean, as diffuse
newmtl Floor
Kd 0.5 0.5 0.5

# roughconductor (metal), no diffuse part
newmtl DoorHandle
Kd 0 0 0
Ks 1 1 1

newmtl Hinge
Kd 0 0 0
Ks 1 1 1

# area emitter, radiance 1000 (Mitsuba units), reflectance 0
newmtl Light
Kd 0 0 0
Ke 1000 1000 1000
"""
(out / 'veach_ajar.mtl').write_text(mtl)
(out / 'textures').mkdir(exist_ok=True)
oiio = str(Path(sys.executable).parent / 'oiiotool')
for a, b in (('landscape-with-a-lake.jpg', 'landscape.jpg'), ('table.jpg', 'table.jpg'),
             ('cherry-wood-texture.jpg', 'door.jpg')):
    subprocess.run([oiio, str(src / 'textures' / a), '--resize:filter=lanczos3', '512x0' if 'table' not in a else '0x768',
                    '--compression', 'jpeg:90', '-o', str(out / 'textures' / b)], check=True)
