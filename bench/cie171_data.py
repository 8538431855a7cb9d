"""The LM-63-2002 standard's example file (its annex), used by the flux-conservation case."""

LM63_EXAMPLE = """IESNA:LM-63-2002
[TEST] ABC1234 ABC Laboratories
[MANUFAC] Aardvark Lighting Inc.
[LUMCAT] SKYVIEW 123-XYZ-abs-400
[LUMINAIRE] Wide beam flood to be used without tilt
[LAMPCAT] MH400-CLEAR
[LAMP] Metal Halide, 400 Watts
[BALLASTCAT] Global Ballast No. 4020
[BALLAST] 400W 277V MH
[OTHER] This luminaire is useful as an indirect flood
[MORE] and to reduce light pollution in down light
[MORE] applications.
[SEARCH] POLLUTION SPORTS INDIRECT
[_USERDEFINED] Sports lighting
TILT=INCLUDE
1
13
0 15 30 45 60 75 90 105 120 135 150 165 180
1.0 .95 .94 .90 .88 .87 .98 .87 .88 .90 .94 .95 1.0
1 50000 1 5 3 1 1 .5 .6 0
1.0 1.0 495
0 22.5 45 67.5 90
0 45 90
10000 50000 25000 10000 5000
10000 35000 16000 8000 3000
10000 20000 10000 5000 1000
"""
