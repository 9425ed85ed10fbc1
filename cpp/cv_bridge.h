// Thin C++ layer over OpenCV for lumiprobe: feature detection, descriptor
// matching, robust homography fitting. Every function takes and returns plain
// buffers owned by Rust; OpenCV types never cross the bridge. Exceptions thrown
// here are turned into Rust errors by cxx.
#pragma once

#include <memory>
#include <mutex>
#include "rust/cxx.h"

namespace lumiprobe {

struct Features;
struct Homography;
struct DisParams;

// A descriptor index over one image's features, built once and queried many times
// (probe faces are indexed once per probe and rotation).
class MatchIndex {
public:
  struct Impl;
  explicit MatchIndex(std::unique_ptr<Impl> impl);
  ~MatchIndex();
  Impl &impl() const { return *impl_; }
  std::mutex &lock() const { return lock_; }

private:
  std::unique_ptr<Impl> impl_;
  mutable std::mutex lock_;
};

void set_num_threads(int32_t n);

Features detect_features(rust::Slice<const uint8_t> gray, int32_t width,
                         int32_t height, int32_t detector,
                         int32_t max_features, double threshold,
                         float blur_sigma);

std::unique_ptr<MatchIndex> build_index(const Features &train,
                                        int32_t flann_checks);

rust::Vec<int32_t> match_ratio(const MatchIndex &index, const Features &query,
                               float ratio);

Homography find_homography(rust::Slice<const float> src,
                           rust::Slice<const float> dst, double threshold,
                           int32_t max_iters, double confidence,
                           int32_t method);

// glibc's malloc: blocks up to `bytes` from the heap (not fresh mappings), and
// up to twice that kept when freed. A no-op elsewhere.
void keep_freed_memory(size_t bytes);

// Dense optical flow (DIS) from `a` to `b`: a(x) ~ b(x + flow(x)), written to
// `out` (Rust-owned, 2 * width * height floats) as interleaved (dx, dy) per pixel.
void dis_flow(rust::Slice<const uint8_t> a, rust::Slice<const uint8_t> b,
              int32_t width, int32_t height, const DisParams &params,
              rust::Slice<float> out);

} // namespace lumiprobe
