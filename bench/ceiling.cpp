// The ceiling of bench/raytrace.py: Embree from C++, rtcIntersect16 on coherent 4x4 pixel tiles.
//
// Reads one scene + views file (written by bench/raytrace.py, layout below), traces every
// view's pixel window with packets of 16 rays (one 4x4 tile each, RTC coherent flag), on T
// std::threads pulling tile rows from a shared counter, and prints one JSON line:
//   {"wall_s": best wall over R repeats, "rays": rays cast per repeat, "hits": hits}
// No post-processing: first hits only, the least work any backend must do.
//
// Input (little endian): int32 nv, nf, nviews, threads, repeat, width, height; float32 far;
// float32 vertices[nv*3]; int32 faces[nf*3]; float32 px[width], py[height];
// per view: float32 position[3], float32 rotation[9] (row-major, columns = camera axes),
// int32 window[4] (rows v0, v1, columns u0, u1).
//
// Builds against Embree 4 (embree4/rtcore.h) or Embree 3 (embree3/rtcore.h, Debian's
// libembree-dev), whichever is found; bench/raytrace.py compiles it with g++ -O3 -march=native.

#if __has_include(<embree4/rtcore.h>)
#include <embree4/rtcore.h>
#else
#include <embree3/rtcore.h>
#endif

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <algorithm>
#include <thread>
#include <vector>

struct View {
  float pos[3];
  float rot[9];
  int32_t win[4];
};

template <class T>
static void read(FILE* f, T* out, size_t n) {
  if (fread(out, sizeof(T), n, f) != n) {
    fprintf(stderr, "ceiling: short input\n");
    exit(2);
  }
}

static RTCScene build(RTCDevice dev, const std::vector<float>& v, const std::vector<int32_t>& t) {
  RTCScene scene = rtcNewScene(dev);
  rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vb = (float*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                             3 * sizeof(float), v.size() / 3);
  auto* ib = (uint32_t*)rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                3 * sizeof(uint32_t), t.size() / 3);
  std::copy(v.begin(), v.end(), vb);
  std::copy(t.begin(), t.end(), ib);
  rtcCommitGeometry(g);
  rtcAttachGeometry(scene, g);
  rtcReleaseGeometry(g);
  rtcCommitScene(scene);
  return scene;
}

// One 4-row strip of a view's window, as 4x4 tiles; returns hits.
static long strip(RTCScene scene, const View& w, int v, const float* px, const float* py,
                  float far) {
  long hits = 0;
  RTCRayHit16 rh;
  alignas(64) int valid[16];
#if RTC_VERSION_MAJOR >= 4
  RTCIntersectArguments args;
  rtcInitIntersectArguments(&args);
  args.flags = RTC_RAY_QUERY_FLAG_COHERENT;
#else
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
#endif
  const float* R = w.rot;
  for (int u = w.win[2]; u < w.win[3]; u += 4) {
    for (int k = 0; k < 16; ++k) {
      int row = v + k / 4, col = u + k % 4;
      valid[k] = (row < w.win[1] && col < w.win[3]) ? -1 : 0;
      float x = valid[k] ? px[col] : 0.f, y = valid[k] ? py[row] : 0.f;
      rh.ray.org_x[k] = w.pos[0];
      rh.ray.org_y[k] = w.pos[1];
      rh.ray.org_z[k] = w.pos[2];
      rh.ray.dir_x[k] = x * R[0] + y * R[1] + R[2];
      rh.ray.dir_y[k] = x * R[3] + y * R[4] + R[5];
      rh.ray.dir_z[k] = x * R[6] + y * R[7] + R[8];
      rh.ray.tnear[k] = 0.f;
      rh.ray.tfar[k] = far;
      rh.ray.time[k] = 0.f;
      rh.ray.mask[k] = 0xFFFFFFFF;
      rh.ray.flags[k] = 0;
      rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
    }
#if RTC_VERSION_MAJOR >= 4
    rtcIntersect16(valid, scene, &rh, &args);
#else
    rtcIntersect16(valid, scene, &ctx, &rh);
#endif
    for (int k = 0; k < 16; ++k) hits += valid[k] && rh.hit.geomID[k] != RTC_INVALID_GEOMETRY_ID;
  }
  return hits;
}

int main(int argc, char** argv) {
  FILE* f = argc > 1 ? fopen(argv[1], "rb") : stdin;
  if (!f) return 2;
  int32_t head[7];
  float far;
  read(f, head, 7);
  read(f, &far, 1);
  int nv = head[0], nf = head[1], nviews = head[2], threads = head[3], repeat = head[4];
  int width = head[5], height = head[6];
  std::vector<float> vertices(3 * (size_t)nv), px(width), py(height);
  std::vector<int32_t> faces(3 * (size_t)nf);
  std::vector<View> views(nviews);
  read(f, vertices.data(), vertices.size());
  read(f, faces.data(), faces.size());
  read(f, px.data(), px.size());
  read(f, py.data(), py.size());
  for (auto& w : views) {
    read(f, w.pos, 3);
    read(f, w.rot, 9);
    read(f, w.win, 4);
  }
  RTCDevice dev = rtcNewDevice(nullptr);
  RTCScene scene = build(dev, vertices, faces);
  std::vector<std::pair<int, int>> strips;  // (view, first row)
  long rays = 0;
  for (int j = 0; j < nviews; ++j) {
    for (int v = views[j].win[0]; v < views[j].win[1]; v += 4) strips.push_back({j, v});
    rays += (long)(views[j].win[1] - views[j].win[0]) * (views[j].win[3] - views[j].win[2]);
  }
  double best = 1e300;
  long hits = 0;
  for (int r = 0; r < repeat; ++r) {
    std::atomic<size_t> next{0};
    std::atomic<long> total{0};
    auto work = [&] {
      long h = 0;
      for (size_t i; (i = next.fetch_add(1)) < strips.size();)
        h += strip(scene, views[strips[i].first], strips[i].second, px.data(), py.data(), far);
      total += h;
    };
    auto t0 = std::chrono::steady_clock::now();
    std::vector<std::thread> pool;
    for (int t = 0; t < threads; ++t) pool.emplace_back(work);
    for (auto& t : pool) t.join();
    double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    best = wall < best ? wall : best;
    hits = total;
  }
  printf("{\"wall_s\": %.6f, \"rays\": %ld, \"hits\": %ld, \"embree\": %d}\n", best, rays, hits,
         RTC_VERSION_MAJOR);
  rtcReleaseScene(scene);
  rtcReleaseDevice(dev);
  return 0;
}
