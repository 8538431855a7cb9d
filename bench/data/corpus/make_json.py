"""Write corpus.json from the files (stats.py) plus the hand-written facts below."""
import json
from pathlib import Path
from stats import obj_stats, glb_stats

here = Path(__file__).parent
SCENES = [
    dict(name='cornell_box', file='cornell_box/CornellBox-Original.obj', format='obj', kind='interior',
         unit='not stated in the file; the real box is 0.556 m wide and this one is about 2 units, so 1 unit ~ 0.28 m',
         up='+y (floor at y = 0, ceiling at y = 1.99; not stated, read off the geometry)',
         light={'type': 'emissive material', 'material': 'light', 'Ke': [17, 12, 4],
                'note': 'the ceiling lamp is in the file; nothing else needed'},
         observer={'position': [0.0, 1.0, 3.4], 'look_at': [0.0, 1.0, 0.0]},
         textured=False),
    dict(name='veach_ajar', file='veach_ajar/veach_ajar.obj', format='obj', kind='interior',
         unit='not stated; consistent with metres (door 2.78 tall, room 3.8 high)',
         up='+y (Mitsuba scene; floor at y ~ 0, camera up +y)',
         light={'type': 'emissive material', 'material': 'Light', 'Ke': [1000, 1000, 1000],
                'note': 'a 1.46 x 2.64 rectangle centred at (-4.44, 1.51, -4.44), emitting towards -z; as in the original scene it sits '
                        'beyond the ajar door, so the camera room is lit mostly through the door gap'},
         observer={'position': [4.05402, 1.61647, -2.30652], 'direction': [-0.990015, -0.0322983, -0.137213],
                   'note': 'the scene.xml camera (fov 60)'},
         textured=True),
    dict(name='kenney_suburb', file='kenney_suburb/kenney_suburb.glb', format='glb', kind='exterior',
         unit='m (glTF); assembled at 8x the kit scale so a house is about 10 m wide',
         up='+y (glTF)',
         light={'type': 'sun + sky', 'sun_elevation_deg': 45, 'sun_azimuth_deg': 135,
                'azimuth_convention': 'clockwise from north, north = -z, east = +x',
                'sky': 'CIE overcast or clear, horizontal illuminance 10000 lux'},
         observer={'position': [0.0, 1.7, 20.0], 'look_at': [0.0, 1.7, 0.0], 'note': 'standing on the north-south road'},
         textured=True),
    dict(name='kenney_retro_urban', file='kenney_retro_urban/kenney_retro_urban.glb', format='glb', kind='exterior',
         unit='m (glTF); assembled at 4x the kit scale (a storey 4 m)',
         up='+y (glTF)',
         light={'type': 'sun + sky', 'sun_elevation_deg': 30, 'sun_azimuth_deg': 225,
                'azimuth_convention': 'clockwise from north, north = -z, east = +x',
                'sky': 'CIE overcast or clear, horizontal illuminance 10000 lux'},
         observer={'position': [-20.0, 1.7, 0.0], 'look_at': [0.0, 1.7, 0.0], 'note': 'on the east-west road'},
         textured=True),
]
out = {'about': 'Real third-party scenes for pydynrad tests and bench; see README.md and LICENSES.md. '
                'Counts parsed by hand off the files (OBJ: `v` lines and `f` lines, an n-gon = n - 2 '
                'triangles; GLB: POSITION accessor counts and index counts / 3); texture means over the '
                'decoded image with OpenImageIO (8-bit values / 255 = "srgb", IEC 61966-2-1 decoded = '
                '"linear"; RGB channels, alpha not premultiplied and not applied). Regenerate: python make_json.py',
       'scenes': []}
for s in SCENES:
    f = here / s['file']
    nv, nt, mats = (obj_stats if s['format'] == 'obj' else glb_stats)(f)
    d = dict(s)
    d['bytes'] = sum(p.stat().st_size for p in f.parent.rglob('*') if p.is_file())
    d['triangles'] = nt; d['vertices'] = nv; d['materials'] = len(mats)
    d['textured_materials'] = {k: v.get('map_Kd', v.get('baseColorTexture')) for k, v in mats.items()
                               if 'texture' in v}
    d['emissive_materials'] = {k: v.get('Ke', v.get('emissiveFactor')) for k, v in mats.items()
                               if any(x > 0 for x in v.get('Ke', v.get('emissiveFactor', [0])))}
    d['per_material'] = mats
    out['scenes'].append(d)
(here / 'corpus.json').write_text(json.dumps(out, indent=1) + '\n')
for d in out['scenes']:
    print(d['name'], d['bytes'], d['triangles'], d['vertices'], d['materials'], list(d['textured_materials']), d['emissive_materials'])
