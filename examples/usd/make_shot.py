"""Write a small animated USD shot with Pixar's usd-core: the sample cloud (data/cloud.vdb,
one copy per frame, as a simulation writes a sequence) drifting along +X under a sun and beside a
sphere light, frames 1-4.

    python make_shot.py OUT_DIR        (needs `pip install usd-core`)

The shot is saved as shot.usda, the text layer usd-core and Solaris write (its density's
filePath time-sampled per frame); a .usdc or .usdz of the same stage bakes the same bytes.
"""

import pathlib
import shutil
import sys

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdVol

out = pathlib.Path(sys.argv[1])
root = pathlib.Path(__file__).resolve().parents[2]
(out / "cache").mkdir(parents=True, exist_ok=True)
frames = range(1, 5)
for f in frames:
    shutil.copy(root / "data" / "cloud.vdb", out / "cache" / f"cloud.{f:04d}.vdb")

st = Usd.Stage.CreateNew(str(out / "shot.usda"))
UsdGeom.SetStageUpAxis(st, UsdGeom.Tokens.y)
st.SetStartTimeCode(frames[0])
st.SetEndTimeCode(frames[-1])
UsdGeom.Xform.Define(st, "/World")
cloud = UsdVol.Volume.Define(st, "/World/fx/cloud")
xf = UsdGeom.Xformable(cloud)
move, turn = xf.AddTranslateOp(), xf.AddRotateYOp()
density = UsdVol.OpenVDBAsset.Define(st, "/World/fx/cloud/density")
density.GetFieldNameAttr().Set("density")
cloud.CreateFieldRelationship("density", density.GetPath())
cloud.GetPrim().CreateAttribute("umbra:densityScale", Sdf.ValueTypeNames.Float).Set(1.5)
for i, f in enumerate(frames):
    move.Set(Gf.Vec3d(0.6 * i, 0.0, 0.0), f)          # drifting along +X
    turn.Set(8.0 * i, f)                              # and turning slowly
    density.GetFilePathAttr().Set(Sdf.AssetPath(f"./cache/cloud.{f:04d}.vdb"), f)

lights = UsdGeom.Xform.Define(st, "/World/lights")
sun = UsdLux.DistantLight.Define(st, "/World/lights/sun")
UsdGeom.Xformable(sun).AddRotateXYZOp().Set(Gf.Vec3f(-70, 25, 0))  # high, from the side
lamp = UsdLux.SphereLight.Define(st, "/World/lights/lamp")
UsdGeom.Xformable(lamp).AddTranslateOp().Set(Gf.Vec3d(-6.0, 1.5, 0.5))
st.Save()
print(f"wrote {out / 'shot.usda'}: frames {frames[0]}-{frames[-1]}, lights sun and lamp")
