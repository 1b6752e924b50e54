// NanoVDB peer for bench/peer.sh: the orthographic transmittance view of bench/programs/ortho_view.rs
// rendered by a ray marcher written the way one would write it on NanoVDB (scalar C++, f32
// values, one ReadAccessor per thread, std::thread over image rows).
//
//   g++ -O3 -march=native -std=c++17 -pthread -o nanovdb_march bench/nanovdb_march.cpp
//   nanovdb_convert -g density FILE.vdb FILE.nvdb        # Debian libnanovdb-tools
//   nanovdb_march FILE.nvdb --grid density --scale 5 --dir=0.6,-0.35,-1 --center=-2.07,1.21,1.93
//       --up=0,1,0 --frame 4.4 --res 512x512 --step 0.5 --threads 2 [--sampler leaf|nanovdb]
//       [--reps 1] --out t.exr
//   nanovdb_march FILE.nvdb --scale 5 --step 1 --threads 2 --segments rays.csv [--out t.f32]
//       (a query batch: see `segments` below)
//
// Camera (as bench/programs/ortho_view.rs and vdb_render -camera ortho): d = normalise(dir),
// u = normalise(up - (up.d) d), r = d x u; pixel (i, j), row 0 at the top, starts at
// center + r (2 (i + .5) / W - 1) frame / 2 + u (1 - 2 (j + .5) / H) (frame / 2) H / W and runs
// along d for t in [0, inf). T = exp(-tau), tau = scale (per world unit) x the integral of the
// trilinear field along the ray. The field is OpenVDB's BoxSampler: voxel (i, j, k) is the index
// point (i, j, k) (NanoVDB keeps OpenVDB's convention), trilinear in each cell [i, i+1]^3.
//
// Per ray:
// 1. The ray goes to index space (the grid's inverse map, direction made unit, so t and the step
//    are in voxels) and is clipped to the grid's index bbox widened by one voxel each way (the
//    trilinear field of the voxels in [lo, hi] is non-zero on (lo - 1, hi + 1)).
// 2. Empty space is skipped with NanoVDB's HDDA over the tree (nanovdb/util/HDDA.h): where the
//    tree has leaves (inside lower nodes) the HDDA steps from 8^3 block to 8^3 block
//    (HDDA::step, dim 8); at a block whose node is an empty or tile node of the upper or root
//    level (ReadAccessor::getDim 128 or 4096) it is re-initialised at that size and leaps the
//    node. It is (re-)initialised a hair (1e-4 voxel) past the entry time: HDDA::update() at the
//    exact boundary time can land back in the node just left, and ZeroCrossing's 1.0001-voxel
//    forward jump would skip data. What the tree holds at a block (ReadAccessor::probeLeaf,
//    getDim, getValue) is memoised per thread in a small direct-mapped table.
// 3. The topology is dilated by one voxel below every active block: at q in (8b - 1, 8b) the
//    trilinear stencil already reads voxel 8b. An 8^3 block that holds a leaf (or a non-zero tile)
//    is a whole span; an empty block contributes the part of the ray in its top strip
//    {q_a > org_a + 7} on each axis a whose +8 neighbour block (and diagonal neighbours) holds
//    data; a big empty node is walked block by block only inside its own top strips. Touching
//    spans are merged (streaming, in ray order).
// 4. Each merged span [a, b] is sampled with the midpoint rule: n = ceil((b - a) / step) equal
//    pieces, one trilinear lookup at each piece's midpoint.
// 5. Trilinear lookups (--sampler leaf, the default) keep the 8 corners of the current cell
//    between samples and read a new cell's corners straight from the leaf's value array, or, for
//    a cell on a leaf's upper face (1 - (7/8)^3 = 33 % of cells), from the neighbour leaves. --sampler nanovdb uses nanovdb::SampleFromVoxels<ReadAccessor,
//    1, false> (8 ReadAccessor::getValue per lookup: the baseline).
//
// Prints one JSON line: load and render seconds ("render_s", median of --reps, excludes the
// load and the EXR write), samples (lookups) per ray, spans per ray. Writes an uncompressed
// single-channel float EXR (channel T, row 0 at the top).

#include <nanovdb/NanoVDB.h>
#include <nanovdb/util/HDDA.h>
#include <nanovdb/util/IO.h>
#include <nanovdb/util/Ray.h>
#include <nanovdb/util/SampleFromVoxels.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

using GridT = nanovdb::FloatGrid;
using AccT = GridT::AccessorType;
using LeafT = nanovdb::NanoLeaf<float>;
using RayT = nanovdb::Ray<float>;
using Vec3f = nanovdb::Vec3f;
using Vec3d = nanovdb::Vec3d;
using Coord = nanovdb::Coord;

namespace {

constexpr float kNudge = 1e-4f;    // voxels past a node's entry time, to pick the node
constexpr float kTouch = 1e-5f;    // spans closer than this (voxels) are merged
constexpr float kInf = 1e30f;
constexpr uint32_t kBlockTable = 1u << 12; // entries of the per-thread block table
alignas(64) const float kZeros[512] = {};    // the values of an empty 8^3 block

// What the tree holds at one 8^3 block, memoised per thread (neighbouring rays and the trilinear
// stencils of neighbouring samples ask about the same blocks again and again).
// Insert the interval [a, b] into the n intervals [lo[i], hi[i]] kept sorted by start.
inline void insertByStart(float* lo, float* hi, int& n, float a, float b)
{
    int i = n++;
    while (i > 0 && lo[i - 1] > a) {
        lo[i] = lo[i - 1];
        hi[i] = hi[i - 1];
        --i;
    }
    lo[i] = a;
    hi[i] = b;
}

struct Block {
    int32_t x = std::numeric_limits<int32_t>::min(), y = 0, z = 0;
    uint32_t dim = 0;            // 8 inside a lower node, else the empty / tile node's size (128, 4096)
    const LeafT* leaf = nullptr; // the leaf, if there is one
    float value = 0.f;           // without a leaf: the tile's value, or the background
    uint8_t up = 0;              // bit m: the block at origin + 8 (m & 1, m >> 1 & 1, m >> 2 & 1) is occupied
    bool upKnown = false;
    bool occupied() const { return leaf || value != 0.f; }
};

struct Counters {
    uint64_t samples = 0;
    uint64_t spans = 0;
};

// One thread's marcher: its own accessor, block table, stencil cache and span state.
template<bool LeafSampler>
class Marcher {
public:
    Marcher(const GridT& grid, float step) : mAcc(grid.getAccessor()), mStep(step), mBlocks(kBlockTable) {}

    // Optical depth in voxels (the integral of the field along the unit index-space ray) over
    // [t0, t1], which the caller has clipped to the widened index bbox.
    double opticalDepth(const RayT& ray, float t0, float t1, Counters& c)
    {
        mRay = &ray;
        mHave = false;
        mTau = 0.0;
        mCounters = &c;
        walk(t0, t1, false);
        if (mHave)
            integrate(mA, mB);
        return mTau;
    }

private:
    const Block& blockAt(const Coord& o) // o: a block origin (multiple of 8)
    {
        const uint32_t h = (uint32_t(o[0] >> 3) * 73856093u ^ uint32_t(o[1] >> 3) * 19349663u ^
                            uint32_t(o[2] >> 3) * 83492791u) & (kBlockTable - 1);
        Block& b = mBlocks[h];
        if (b.x == o[0] && b.y == o[1] && b.z == o[2])
            return b;
        b.x = o[0];
        b.y = o[1];
        b.z = o[2];
        b.upKnown = false;
        b.leaf = mAcc.probeLeaf(o);
        if (b.leaf) {
            b.dim = 8;
            b.value = 0.f;
        } else {
            b.dim = std::max(8u, uint32_t(mAcc.getDim(o, *mRay)));
            b.value = mAcc.getValue(o);
        }
        return b;
    }

    // Which of the 7 blocks above this one (+x, +y, +z and the diagonals) hold data: an empty
    // block's trilinear strips are non-zero only next to those. Memoised with the block.
    uint8_t upMask(const Coord& o)
    {
        {
            const Block& b = blockAt(o);
            if (b.upKnown)
                return b.up;
        }
        uint8_t up = 0;
        for (int m = 1; m < 8; ++m)
            if (blockAt(Coord(o[0] + ((m & 1) << 3), o[1] + ((m & 2) << 2), o[2] + ((m & 4) << 1))).occupied())
                up |= uint8_t(1u << m);
        Block& b = const_cast<Block&>(blockAt(o)); // the lookups above may have evicted it
        b.up = up;
        b.upKnown = true;
        return up;
    }

    // The HDDA over the tree. Where the tree has leaves (lower nodes), the ray steps from 8^3
    // block to 8^3 block with nanovdb::HDDA::step(); at a block whose node is an empty or tile
    // node of the upper or root level (getDim 128 or 4096), the HDDA is re-initialised at that
    // size to leap the node. force8: inside an empty big node, walk its 8^3 blocks to find the
    // data of neighbouring nodes whose trilinear strip reaches in.
    void walk(float t0, float t1, bool force8)
    {
        const RayT& ray = *mRay;
        float t = t0;
        while (t < t1) {
            const float tq = t + kNudge;
            if (tq >= t1)
                break;
            const Coord ijk = nanovdb::RoundDown<Coord>(ray(tq));
            const Block& b0 = blockAt(ijk & ~7);
            if (!force8 && b0.dim > 8) {
                mHdda.init(ray, tq, t1, int(b0.dim));
                float te = std::min(mHdda.next(), t1);
                if (!(te > tq))
                    te = tq;
                big(mHdda.voxel(), int(b0.dim), b0.value, t, te);
                t = te;
                continue;
            }
            mHdda.init(ray, tq, t1, 8);
            while (true) {
                const Coord org = mHdda.voxel();
                const Block& b = blockAt(org);
                if (!force8 && b.dim > 8)
                    break; // t is this node's entry: leap it in the outer loop
                const float te = std::max(t, std::min(mHdda.next(), t1));
                block(org, b.occupied(), t, te);
                t = te;
                if (te >= t1 || !mHdda.step())
                    break;
            }
        }
    }

    // The part of [ta, tb] where the ray is above the plane q_axis = c.
    void above(int axis, float c, float ta, float tb, float& lo, float& hi) const
    {
        const RayT& ray = *mRay;
        const float o = ray.eye()[axis], d = ray.dir()[axis];
        lo = ta;
        hi = tb;
        if (d > 0.f)
            lo = std::max(ta, (c - o) * ray.invDir()[axis]);
        else if (d < 0.f)
            hi = std::min(tb, (c - o) * ray.invDir()[axis]);
        else if (!(o > c))
            hi = lo - 1.f; // empty
    }

    void block(const Coord& org, bool own, float ta, float tb)
    {
        if (own) {
            emit(ta, tb);
            return;
        }
        const uint8_t up = upMask(org);
        if (!up)
            return;
        const RayT& ray = *mRay;
        const Vec3f pa = ray(ta), pb = ray(tb);
        float lo[3] = {}, hi[3] = {};
        int near = 0;
        for (int a = 0; a < 3; ++a) {
            const float top = float(org[a] + 7);
            if (std::max(pa[a], pb[a]) > top) {
                above(a, top, ta, tb, lo[a], hi[a]);
                if (hi[a] > lo[a])
                    near |= 1 << a;
            }
        }
        if (!near)
            return;
        float sa[7], sb[7];
        int n = 0;
        for (int m = 1; m < 8; ++m) {
            if ((m & ~near) || !(up & (1u << m)))
                continue;
            float a = ta, b = tb;
            for (int k = 0; k < 3; ++k)
                if (m & (1 << k)) {
                    a = std::max(a, lo[k]);
                    b = std::min(b, hi[k]);
                }
            if (b > a)
                insertByStart(sa, sb, n, a, b);
        }
        for (int i = 0; i < n; ++i)
            emit(sa[i], sb[i]);
    }

    // A tile or the background of an upper node (dim 128) or of the root (dim 4096).
    void big(const Coord& org, int dim, float value, float ta, float tb)
    {
        if (value != 0.f) {
            emit(ta, tb);
            return;
        }
        const RayT& ray = *mRay;
        const Vec3f pa = ray(ta), pb = ray(tb);
        float lo[3], hi[3];
        int n = 0;
        for (int a = 0; a < 3; ++a) {
            const float top = float(org[a] + dim - 1);
            if (std::max(pa[a], pb[a]) > top) {
                float l, h;
                above(a, top, ta, tb, l, h);
                if (h > l)
                    insertByStart(lo, hi, n, l, h);
            }
        }
        // walk the union of the strips block by block
        float cur = -kInf;
        for (int i = 0; i < n; ++i) {
            const float l = std::max(lo[i], cur);
            if (hi[i] > l) {
                walk(l, hi[i], true);
                cur = hi[i];
            }
        }
    }

    void emit(float a, float b)
    {
        if (!(b > a))
            return;
        if (mHave && a <= mB + kTouch) {
            mB = std::max(mB, b);
            return;
        }
        if (mHave)
            integrate(mA, mB);
        mHave = true;
        mA = a;
        mB = b;
    }

    void integrate(float a, float b)
    {
        const RayT& ray = *mRay;
        const Vec3f o = ray.eye(), d = ray.dir();
        const float len = b - a;
        const int n = std::max(1, int(std::ceil(len / mStep - 1e-4f)));
        const float h = len / float(n), t0 = a + 0.5f * h;
        float sum = 0.f;
        for (int k = 0; k < n; ++k) {
            const float t = std::fma(float(k), h, t0);
            const Vec3f p(std::fma(t, d[0], o[0]), std::fma(t, d[1], o[1]), std::fma(t, d[2], o[2]));
            if constexpr (LeafSampler)
                sum += sampleLeaf(p);
            else
                sum += nanovdb::SampleFromVoxels<AccT, 1, false>(mAcc)(p);
        }
        mTau += double(sum) * double(h);
        mCounters->samples += uint64_t(n);
        mCounters->spans += 1;
    }

    // Trilinear. The 8 corners of the current cell are kept between samples (at step 0.25 a
    // ray takes ~2.5 samples per cell). A new cell inside one leaf reads them from the leaf's
    // value array; a cell on a leaf's upper face reads them from the +x/+y/+z neighbour leaves
    // (tile value or background where there is no leaf).
    inline __attribute__((always_inline)) float sampleLeaf(const Vec3f& p)
    {
        const float fx = std::floor(p[0]), fy = std::floor(p[1]), fz = std::floor(p[2]);
        const int ix = int(fx), iy = int(fy), iz = int(fz);
        const float u = p[0] - fx, v = p[1] - fy, w = p[2] - fz;
        if (ix != mCell[0] || iy != mCell[1] || iz != mCell[2])
            loadCell(ix, iy, iz);
        const float* c = mCorner;
        const float c00 = c[0] + w * (c[1] - c[0]), c01 = c[2] + w * (c[3] - c[2]);
        const float c10 = c[4] + w * (c[5] - c[4]), c11 = c[6] + w * (c[7] - c[6]);
        const float c0 = c00 + v * (c01 - c00), c1 = c10 + v * (c11 - c10);
        return c0 + u * (c1 - c0);
    }

    // mCorner[(dx << 2) | (dy << 1) | dz] = value at (ix + dx, iy + dy, iz + dz)
    void loadCell(int ix, int iy, int iz)
    {
        mCell[0] = ix;
        mCell[1] = iy;
        mCell[2] = iz;
        const Coord o(ix & ~7, iy & ~7, iz & ~7);
        if (o != mBase) {
            mBase = o;
            mProbed = 0;
        }
        const int lx = ix & 7, ly = iy & 7, lz = iz & 7;
        const int off = (lx << 6) | (ly << 3) | lz;
        if (lx != 7 && ly != 7 && lz != 7) {
            const LeafT* leaf = neighbour(0);
            if (!leaf) {
                std::fill(mCorner, mCorner + 8, mTile[0]);
                return;
            }
            const float* val = leaf->data()->mValues + off;
            mCorner[0] = val[0];
            mCorner[1] = val[1];
            mCorner[2] = val[8];
            mCorner[3] = val[9];
            mCorner[4] = val[64];
            mCorner[5] = val[65];
            mCorner[6] = val[72];
            mCorner[7] = val[73];
            return;
        }
        // On an upper face: the corners past it come from the neighbour leaves (the subsets m
        // of the faces crossed); a block without a leaf reads from kZeros when its value is 0.
        const int bx = lx == 7, by = ly == 7, bz = lz == 7, faces = bx | (by << 1) | (bz << 2);
        const int sx = bx ? -448 : 64, sy = by ? -56 : 8, sz = bz ? -7 : 1;
        const float* v[8];
        bool tile = false;
        for (int m = faces;; m = (m - 1) & faces) {
            const LeafT* leaf = neighbour(m);
            v[m] = leaf ? leaf->data()->mValues : kZeros;
            tile |= !leaf && mTile[m] != 0.f;
            if (m == 0)
                break;
        }
        const int mx = bx, my = by << 1, mz = bz << 2;
        if (!tile) {
            mCorner[0] = v[0][off];
            mCorner[1] = v[mz][off + sz];
            mCorner[2] = v[my][off + sy];
            mCorner[3] = v[my | mz][off + sy + sz];
            mCorner[4] = v[mx][off + sx];
            mCorner[5] = v[mx | mz][off + sx + sz];
            mCorner[6] = v[mx | my][off + sx + sy];
            mCorner[7] = v[mx | my | mz][off + sx + sy + sz];
            return;
        }
        for (int k = 0; k < 8; ++k) { // a non-zero tile among the neighbours (rare)
            const int dx = k >> 2, dy = (k >> 1) & 1, dz = k & 1;
            const int m = (dx & bx) | ((dy & by) << 1) | ((dz & bz) << 2);
            mCorner[k] = mNb[m] ? v[m][off + dx * sx + dy * sy + dz * sz] : mTile[m];
        }
    }

    // The leaf at mBase + 8 (m & 1, m >> 1 & 1, m >> 2 & 1), looked up once per base leaf; when
    // there is none, mTile[m] holds the value of that 8^3 block (a tile's, or the background).
    const LeafT* neighbour(int m)
    {
        if (!(mProbed & (1u << m))) {
            mProbed |= 1u << m;
            const Block& b = blockAt(Coord(mBase[0] + ((m & 1) << 3), mBase[1] + ((m & 2) << 2), mBase[2] + ((m & 4) << 1)));
            mNb[m] = b.leaf;
            mTile[m] = b.value;
        }
        return mNb[m];
    }

    AccT mAcc;
    float mStep;
    std::vector<Block> mBlocks;
    nanovdb::HDDA<RayT, Coord> mHdda;
    const RayT* mRay = nullptr;
    Counters* mCounters = nullptr;
    bool mHave = false;
    float mA = 0.f, mB = 0.f;
    double mTau = 0.0;
    int mCell[3] = {std::numeric_limits<int32_t>::min(), 0, 0};
    float mCorner[8] = {};
    Coord mBase = Coord(std::numeric_limits<int32_t>::max());
    uint32_t mProbed = 0;
    const LeafT* mNb[8] = {};
    float mTile[8] = {};
};

Vec3d parseVec(const std::string& s)
{
    double v[3];
    if (std::sscanf(s.c_str(), "%lf,%lf,%lf", &v[0], &v[1], &v[2]) != 3)
        throw std::runtime_error("expected x,y,z: " + s);
    return Vec3d(v[0], v[1], v[2]);
}

// Uncompressed single-part scanline OpenEXR, one FLOAT channel, row 0 at the top.
void writeExr(const std::string& path, const std::string& channel, int w, int h, const std::vector<float>& px)
{
    std::string hd;
    auto i32 = [&](int32_t x) { hd.append(reinterpret_cast<const char*>(&x), 4); };
    auto f32 = [&](float x) { hd.append(reinterpret_cast<const char*>(&x), 4); };
    auto attr = [&](const char* name, const char* type, int32_t size) {
        hd += name;
        hd += '\0';
        hd += type;
        hd += '\0';
        i32(size);
    };
    const uint32_t magic = 20000630, version = 2;
    hd.append(reinterpret_cast<const char*>(&magic), 4);
    hd.append(reinterpret_cast<const char*>(&version), 4);
    attr("channels", "chlist", int32_t(channel.size() + 1 + 16 + 1));
    hd += channel;
    hd += '\0';
    i32(2); // FLOAT
    hd.append(4, '\0'); // pLinear, reserved
    i32(1);
    i32(1);
    hd += '\0';
    attr("compression", "compression", 1);
    hd += '\0'; // NO_COMPRESSION
    for (const char* win : {"dataWindow", "displayWindow"}) {
        attr(win, "box2i", 16);
        i32(0);
        i32(0);
        i32(w - 1);
        i32(h - 1);
    }
    attr("lineOrder", "lineOrder", 1);
    hd += '\0'; // INCREASING_Y
    attr("pixelAspectRatio", "float", 4);
    f32(1.f);
    attr("screenWindowCenter", "v2f", 8);
    f32(0.f);
    f32(0.f);
    attr("screenWindowWidth", "float", 4);
    f32(1.f);
    hd += '\0';
    const uint64_t line = 8 + uint64_t(w) * 4;
    uint64_t off = hd.size() + uint64_t(h) * 8;
    for (int y = 0; y < h; ++y, off += line)
        hd.append(reinterpret_cast<const char*>(&off), 8);
    for (int y = 0; y < h; ++y) {
        i32(y);
        i32(w * 4);
        hd.append(reinterpret_cast<const char*>(px.data() + size_t(y) * w), size_t(w) * 4);
    }
    const std::string tmp = path + ".tmp";
    std::ofstream f(tmp, std::ios::binary);
    f.write(hd.data(), std::streamsize(hd.size()));
    f.close();
    if (!f || std::rename(tmp.c_str(), path.c_str()) != 0)
        throw std::runtime_error("cannot write " + path);
}

// Run work(0..threads-1) on that many threads (the caller's as thread 0); the wall seconds.
template<typename Work>
double timedOnThreads(int threads, const Work& work)
{
    const auto t0 = std::chrono::steady_clock::now();
    std::vector<std::thread> pool;
    for (int k = 1; k < threads; ++k)
        pool.emplace_back(work, k);
    work(0);
    for (auto& th : pool)
        th.join();
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

template<bool LeafSampler>
double render(const GridT& grid, const std::map<std::string, std::string>& opt, int threads, std::vector<float>& img,
              int w, int hgt, Counters& total)
{
    auto get = [&](const std::string& k, const std::string& d) {
        auto it = opt.find(k);
        return it == opt.end() ? d : it->second;
    };
    const double scale = std::stod(get("scale", "1"));
    const float step = std::stof(get("step", "1"));
    const double frame = std::stod(get("frame", "1"));
    Vec3d dir = parseVec(get("dir", "0,0,-1")), center = parseVec(get("center", "0,0,0")), up = parseVec(get("up", "0,1,0"));
    dir.normalize();
    Vec3d u = up - dir * up.dot(dir);
    u.normalize();
    Vec3d r = dir.cross(u);
    r.normalize();
    const double s = frame / w, x0 = -frame / 2 + s / 2, y0 = frame / 2 * hgt / w - s / 2;

    // index-space direction, made unit; world length of one index-space unit along it
    const Vec3d dIdx = grid.worldToIndexDir(dir);
    const double idxLen = dIdx.length();
    const Vec3f dUnit(float(dIdx[0] / idxLen), float(dIdx[1] / idxLen), float(dIdx[2] / idxLen));
    const double tauScale = scale / idxLen; // per voxel of the unit index ray
    const auto bb = grid.indexBBox();
    const nanovdb::BBox<Vec3f> clip(Vec3f(float(bb.min()[0] - 1), float(bb.min()[1] - 1), float(bb.min()[2] - 1)),
                                    Vec3f(float(bb.max()[0] + 1), float(bb.max()[1] + 1), float(bb.max()[2] + 1)));

    std::atomic<int> nextRow{0};
    std::vector<Counters> counters{size_t(threads)};
    auto work = [&](int tid) {
        Marcher<LeafSampler> m(grid, step);
        Counters& c = counters[size_t(tid)];
        for (int j; (j = nextRow.fetch_add(1)) < hgt;) {
            for (int i = 0; i < w; ++i) {
                const Vec3d ow = center + r * (x0 + i * s) + u * (y0 - j * s);
                const Vec3d oi = grid.worldToIndex(ow);
                RayT ray{Vec3f(float(oi[0]), float(oi[1]), float(oi[2])), dUnit, 0.f, kInf};
                float T = 1.f;
                if (ray.clip(clip)) {
                    const double tau = m.opticalDepth(ray, ray.t0(), ray.t1(), c);
                    T = float(std::exp(-tauScale * tau));
                }
                img[size_t(j) * w + i] = T;
            }
        }
    };
    const double secs = timedOnThreads(threads, work);
    total = Counters{};
    for (const auto& c : counters) {
        total.samples += c.samples;
        total.spans += c.spans;
    }
    return secs;
}

// --segments FILE: world segments, one per line "ox,oy,oz,ex,ey,ez" (the CSV `umbra query
// --rays` reads; a first line that is not numbers is skipped), each marched from o to e as the
// map's rays are (index space, unit direction, clipped to the widened bbox). Returns the seconds
// of the march alone (parsing excluded); T per segment into `out`, the index-space length of the
// clipped segments (voxels crossed) into `voxels`.
template<bool LeafSampler>
double segments(const GridT& grid, const std::vector<double>& rows, double scale, float step, int threads,
                std::vector<float>& out, double& voxels, Counters& total)
{
    const size_t n = rows.size() / 6;
    out.assign(n, 0.f);
    const auto bb = grid.indexBBox();
    const nanovdb::BBox<Vec3f> clip(Vec3f(float(bb.min()[0] - 1), float(bb.min()[1] - 1), float(bb.min()[2] - 1)),
                                    Vec3f(float(bb.max()[0] + 1), float(bb.max()[1] + 1), float(bb.max()[2] + 1)));
    std::atomic<size_t> next{0};
    std::vector<Counters> counters{size_t(threads)};
    std::vector<double> crossed(size_t(threads), 0.0);
    auto work = [&](int tid) {
        Marcher<LeafSampler> m(grid, step);
        Counters& c = counters[size_t(tid)];
        constexpr size_t kChunk = 1024;
        for (size_t k0; (k0 = next.fetch_add(kChunk)) < n;) {
            for (size_t k = k0; k < std::min(n, k0 + kChunk); ++k) {
                const double* r = &rows[6 * k];
                const Vec3d oi = grid.worldToIndex(Vec3d(r[0], r[1], r[2]));
                const Vec3d ei = grid.worldToIndex(Vec3d(r[3], r[4], r[5]));
                const Vec3d dIdx = ei - oi;
                const double len = dIdx.length(); // voxels from o to e
                float T = 1.f;
                if (len > 0.0) {
                    const Vec3f dUnit(float(dIdx[0] / len), float(dIdx[1] / len), float(dIdx[2] / len));
                    RayT ray{Vec3f(float(oi[0]), float(oi[1]), float(oi[2])), dUnit, 0.f, float(len)};
                    if (ray.clip(clip)) {
                        crossed[size_t(tid)] += double(ray.t1() - ray.t0());
                        const double worldLen = Vec3d(r[3] - r[0], r[4] - r[1], r[5] - r[2]).length();
                        const double tau = m.opticalDepth(ray, ray.t0(), ray.t1(), c);
                        T = float(std::exp(-scale * worldLen / len * tau));
                    }
                }
                out[k] = T;
            }
        }
    };
    const double secs = timedOnThreads(threads, work);
    total = Counters{};
    voxels = 0.0;
    for (int k = 0; k < threads; ++k) {
        total.samples += counters[size_t(k)].samples;
        total.spans += counters[size_t(k)].spans;
        voxels += crossed[size_t(k)];
    }
    return secs;
}

std::vector<double> readSegments(const std::string& path)
{
    std::ifstream f(path);
    if (!f)
        throw std::runtime_error("cannot read " + path);
    std::vector<double> rows;
    std::string line;
    while (std::getline(f, line)) {
        double v[6];
        if (std::sscanf(line.c_str(), "%lf,%lf,%lf,%lf,%lf,%lf", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) == 6)
            rows.insert(rows.end(), v, v + 6);
    }
    return rows;
}

} // namespace

int main(int argc, char** argv)
{
    try {
        std::string file;
        std::map<std::string, std::string> opt;
        for (int i = 1; i < argc; ++i) {
            std::string a = argv[i];
            if (a.rfind("--", 0) == 0) {
                auto eq = a.find('=');
                if (eq != std::string::npos)
                    opt[a.substr(2, eq - 2)] = a.substr(eq + 1);
                else if (i + 1 < argc)
                    opt[a.substr(2)] = argv[++i];
                else
                    throw std::runtime_error("missing value for " + a);
            } else {
                file = a;
            }
        }
        if (file.empty())
            throw std::runtime_error("usage: nanovdb_march FILE.nvdb [--grid density] [--scale S] ... --out t.exr");
        auto get = [&](const std::string& k, const std::string& d) {
            auto it = opt.find(k);
            return it == opt.end() ? d : it->second;
        };
        const std::string gridName = get("grid", "density"), sampler = get("sampler", "leaf");
        int threads = std::stoi(get("threads", "0"));
        if (threads <= 0)
            threads = int(std::max(1u, std::thread::hardware_concurrency()));
        const int reps = std::max(1, std::stoi(get("reps", "1")));
        int w = 512, h = 512;
        if (std::sscanf(get("res", "512x512").c_str(), "%dx%d", &w, &h) != 2 || w <= 0 || h <= 0)
            throw std::runtime_error("--res WxH");
        if (sampler != "leaf" && sampler != "nanovdb")
            throw std::runtime_error("--sampler leaf|nanovdb");

        const auto tl = std::chrono::steady_clock::now();
        auto handle = nanovdb::io::readGrid(file, gridName);
        const GridT* grid = handle.grid<float>();
        if (!grid)
            throw std::runtime_error(file + ": no float grid named " + gridName);
        const double loadS = std::chrono::duration<double>(std::chrono::steady_clock::now() - tl).count();

        if (opt.count("segments")) {
            const std::vector<double> rows = readSegments(opt["segments"]);
            const double scale = std::stod(get("scale", "1"));
            const float step = std::stof(get("step", "1"));
            std::vector<float> t;
            std::vector<double> times;
            double voxels = 0.0;
            Counters c;
            for (int k = 0; k < reps; ++k)
                times.push_back(sampler == "leaf" ? segments<true>(*grid, rows, scale, step, threads, t, voxels, c)
                                                  : segments<false>(*grid, rows, scale, step, threads, t, voxels, c));
            std::sort(times.begin(), times.end());
            if (opt.count("out")) {
                std::ofstream f(opt["out"], std::ios::binary);
                f.write(reinterpret_cast<const char*>(t.data()), std::streamsize(t.size() * 4));
            }
            const double n = double(rows.size() / 6), secs = times[times.size() / 2];
            std::printf("{\"file\":\"%s\",\"step\":%s,\"threads\":%d,\"segments\":%.0f,\"load_s\":%.6f,"
                        "\"trace_s\":%.6f,\"mrays_per_s\":%.4f,\"ns_per_voxel\":%.4f,\"voxels_per_ray\":%.3f,"
                        "\"samples_per_ray\":%.3f}\n",
                        file.c_str(), get("step", "1").c_str(), threads, n, loadS, secs, n / secs / 1e6,
                        secs * 1e9 / voxels, voxels / n, double(c.samples) / n);
            return 0;
        }
        std::vector<float> img(size_t(w) * h);
        std::vector<double> times;
        Counters c;
        for (int k = 0; k < reps; ++k)
            times.push_back(sampler == "leaf" ? render<true>(*grid, opt, threads, img, w, h, c)
                                              : render<false>(*grid, opt, threads, img, w, h, c));
        std::sort(times.begin(), times.end());
        if (opt.count("out"))
            writeExr(opt["out"], "T", w, h, img);
        const double rays = double(w) * h;
        std::printf("{\"file\":\"%s\",\"step\":%s,\"sampler\":\"%s\",\"threads\":%d,\"res\":[%d,%d],\"load_s\":%.6f,"
                    "\"render_s\":%.6f,\"rays_per_s\":%.1f,\"samples_per_ray\":%.3f,\"spans_per_ray\":%.3f}\n",
                    file.c_str(), get("step", "1").c_str(), sampler.c_str(), threads, w, h, loadS, times[times.size() / 2],
                    rays / times[times.size() / 2], double(c.samples) / rays, double(c.spans) / rays);
        return 0;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "nanovdb_march: error: %s\n", e.what());
        return 1;
    }
}
