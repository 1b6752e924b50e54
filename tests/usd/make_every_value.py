"""Write tests/usd/every_value.usdc with Pixar's usd-core: a stage holding a value of every
type the crate (.usdc) format stores, in every encoding usd-core picks (inlined scalars, empty,
short and long arrays, integer- and table-compressed float arrays), and every structure the
format nests (dictionaries five deep, references with customData, payloads, list ops, variant
selections, sublayer offsets, time samples of arrays, relationships, connections).

The file is the fixture of `tests/library/usd_corrupt.rs` (umbra must read every valid layer and
never abort on a corrupt one); python/tests/test_usd.py writes the same stage
with the usd-core of the day and reads it through the CLI. Run: python3 make_every_value.py OUT
"""
import sys

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdVol, Vt

S = Sdf.ValueTypeNames

# (value type, a scalar, a long array's element as a function of i)
TYPES = [
    (S.Bool, True, lambda i: i % 3 == 0),
    (S.UChar, 7, lambda i: i % 251),
    (S.Int, -5, lambda i: i * i - 300),
    (S.UInt, 9, lambda i: 3 * i),
    (S.Int64, -(1 << 40), lambda i: (i - 50) << 33),
    (S.UInt64, 1 << 50, lambda i: i << 34),
    (S.Half, 0.5, lambda i: (i % 5) * 0.25),
    (S.Float, 1.25, lambda i: float(i % 7)),
    (S.Double, 3.141592653589793, lambda i: i * 0.1),
    (S.String, "text", lambda i: f"s{i % 4}"),
    (S.Token, "tok", lambda i: f"t{i % 4}"),
    (S.Asset, Sdf.AssetPath("./a.vdb"), lambda i: Sdf.AssetPath(f"./f{i % 3}.vdb")),
    (S.TimeCode, Sdf.TimeCode(4.0), lambda i: Sdf.TimeCode(i * 0.5)),
    (S.Matrix2d, Gf.Matrix2d(2), lambda i: Gf.Matrix2d(i)),
    (S.Matrix3d, Gf.Matrix3d(3), lambda i: Gf.Matrix3d(i)),
    (S.Matrix4d, Gf.Matrix4d(4), lambda i: Gf.Matrix4d(i)),
    (S.Quatd, Gf.Quatd(1, 2, 3, 4), lambda i: Gf.Quatd(i, 0, 1, 0)),
    (S.Quatf, Gf.Quatf(1, 2, 3, 4), lambda i: Gf.Quatf(i, 0, 1, 0)),
    (S.Quath, Gf.Quath(1, 0, 0, 0), lambda i: Gf.Quath(1, 0, 0, 0)),
]
for n in (2, 3, 4):
    for t in "dfhi":
        name = getattr(S, f"Float{n}" if t == "f" else {"d": f"Double{n}", "h": f"Half{n}", "i": f"Int{n}"}[t])
        vec = getattr(Gf, f"Vec{n}{t}")
        TYPES.append((name, vec(*range(1, n + 1)), lambda i, vec=vec, n=n: vec(*[i % 9] * n)))


def main(out):
    st = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(st, "Y")
    st.SetStartTimeCode(1)
    st.SetEndTimeCode(3)
    layer = st.GetRootLayer()
    layer.customLayerData = {"a": {"b": {"c": {"d": {"e": 1, "f": "deep"}}}}, "n": 2.5}
    over = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append(over.identifier)
    layer.subLayerOffsets[0] = Sdf.LayerOffset(10, 2)
    layer.subLayerPaths.clear()  # the anonymous layer cannot be saved; the offsets were written

    world = UsdGeom.Xform.Define(st, "/World")
    p = st.DefinePrim("/World/values", "Scope")
    for k, (ty, scalar, elem) in enumerate(TYPES):
        base = f"v{k}"
        p.CreateAttribute(base, ty).Set(scalar)
        at = ty.arrayType
        p.CreateAttribute(base + "_empty", at).Set([])
        p.CreateAttribute(base + "_short", at).Set([elem(i) for i in range(3)])
        p.CreateAttribute(base + "_long", at).Set([elem(i) for i in range(200)])
        a = p.CreateAttribute(base + "_anim", at)
        for t in (1, 2, 3):
            a.Set([elem(i + t) for i in range(5 * t)], t)
    # Double arrays the crate codes as integers ('i') and as a lookup table ('t').
    p.CreateAttribute("ints_as_doubles", S.DoubleArray).Set([float(i % 40) for i in range(500)])
    p.CreateAttribute("table_doubles", S.DoubleArray).Set([(i % 6) * 0.37 for i in range(500)])
    p.SetCustomData({"x": {"y": {"z": {"w": [1, 2, 3], "s": "v"}}}, "t": Vt.TokenArray(["a", "b"])})
    p.SetAssetInfo({"identifier": Sdf.AssetPath("./x.usd"), "version": "1"})
    p.SetMetadata("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["CollectionAPI:c"]))
    p.SetMetadata("kind", "component")
    p.SetDocumentation("every value")

    ref = st.DefinePrim("/Ref", "Xform")
    ref.CreateAttribute("r", S.Int).Set(1)
    tgt = st.DefinePrim("/World/target", "Scope")
    tgt.GetReferences().AddInternalReference("/Ref", Sdf.LayerOffset(2, 1))
    tgt.GetPayloads().AddPayload(Sdf.Payload("", "/Ref"))
    tgt.GetInherits().AddInherit("/Ref")
    tgt.GetSpecializes().AddSpecialize("/Ref")
    spec = layer.GetPrimAtPath("/World/target")
    spec.referenceList.prependedItems[0] = Sdf.Reference(
        "", "/Ref", Sdf.LayerOffset(2, 1), {"note": "cd", "nested": {"k": 1}})
    vs = tgt.GetVariantSets().AddVariantSet("look")
    for v in ("a", "b"):
        vs.AddVariant(v)
    vs.SetVariantSelection("b")
    with vs.GetVariantEditContext():
        tgt.CreateAttribute("inVariant", S.Float).Set(2.0)
    rel = tgt.CreateRelationship("links")
    rel.SetTargets(["/World/values", "/Ref"])
    c = tgt.CreateAttribute("plug", S.Float)
    c.AddConnection("/World/values.v7")
    tgt.CreateAttribute("tokens", S.Token).Set("x")
    tgt.SetPropertyOrder(["tokens", "plug"])
    world.GetPrim().SetMetadata("primOrder", ["values", "target"]) if False else None
    st.GetPseudoRoot().SetMetadata("documentation", "sink")

    # The shot itself: a volume and a light, so the CLI has something to read.
    vol = UsdVol.Volume.Define(st, "/World/cloud")
    asset = UsdVol.OpenVDBAsset.Define(st, "/World/cloud/density")
    for t in (1, 2, 3):
        asset.GetFilePathAttr().Set(Sdf.AssetPath("./cloud.vdb"), t)
    asset.GetFieldNameAttr().Set("density")
    vol.CreateFieldRelationship("density", asset.GetPath())
    UsdLux.DistantLight.Define(st, "/World/sun")
    st.Export(out)


if __name__ == "__main__":
    main(sys.argv[1])
