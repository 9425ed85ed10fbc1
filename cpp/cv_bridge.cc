// Implementation of the OpenCV layer declared in cv_bridge.h.
#include "lumiprobe/cpp/cv_bridge.h"
#include "lumiprobe/src/cv.rs.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/flann.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <algorithm>
#include <climits>
#if defined(__GLIBC__)
#include <malloc.h>
#endif
#include <cmath>
#include <cstring>

#include <stdexcept>
#include <string>

namespace lumiprobe {

struct MatchIndex::Impl {
  bool binary = false;
  int checks = 32;
  int count = 0;
  cv::Mat train;                          // descriptors (rows = features)
  std::unique_ptr<cv::flann::Index> kd;   // float descriptors
};

MatchIndex::MatchIndex(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MatchIndex::~MatchIndex() = default;

void set_num_threads(int32_t n) { cv::setNumThreads(n); }

namespace {

enum Detector { SIFT = 0, AKAZE = 1, ORB = 2 };

cv::Ptr<cv::Feature2D> make_detector(int32_t detector, int32_t max_features,
                                     double threshold) {
  switch (detector) {
  case SIFT:
    return cv::SIFT::create(max_features > 0 ? max_features : 0, 3,
                            threshold > 0 ? threshold : 0.04);
  case AKAZE:
    return cv::AKAZE::create(cv::AKAZE::DESCRIPTOR_MLDB, 0, 3,
                             threshold > 0 ? threshold : 0.001);
  case ORB:
    return cv::ORB::create(max_features > 0 ? max_features : 500);
  default:
    throw std::invalid_argument("unknown feature detector id " +
                                std::to_string(detector));
  }
}

cv::Mat descriptors_of(const Features &f) {
  if (f.count <= 0 || f.dim <= 0)
    return cv::Mat();
  if (f.binary) {
    if (f.desc_u8.size() != size_t(f.count) * size_t(f.dim))
      throw std::invalid_argument("binary descriptor buffer has wrong size");
    return cv::Mat(f.count, f.dim, CV_8U,
                   const_cast<uint8_t *>(f.desc_u8.data()));
  }
  if (f.desc_f32.size() != size_t(f.count) * size_t(f.dim))
    throw std::invalid_argument("float descriptor buffer has wrong size");
  return cv::Mat(f.count, f.dim, CV_32F,
                 const_cast<float *>(f.desc_f32.data()));
}

} // namespace

Features detect_features(rust::Slice<const uint8_t> gray, int32_t width,
                         int32_t height, int32_t detector,
                         int32_t max_features, double threshold,
                         float blur_sigma) {
  if (width <= 0 || height <= 0 ||
      gray.size() != size_t(width) * size_t(height))
    throw std::invalid_argument("gray image buffer does not match its size");
  cv::Mat img(height, width, CV_8U, const_cast<uint8_t *>(gray.data()));
  if (blur_sigma > 0.0f) {
    cv::Mat smooth;
    cv::GaussianBlur(img, smooth, cv::Size(0, 0), blur_sigma);
    img = smooth;
  }
  auto det = make_detector(detector, max_features, threshold);
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  det->detectAndCompute(img, cv::noArray(), kps, desc);
  Features out;
  out.count = int32_t(kps.size());
  out.dim = desc.empty() ? 0 : desc.cols;
  out.binary = !desc.empty() && desc.type() == CV_8U;
  out.xy.reserve(kps.size() * 2);
  for (const auto &k : kps) {
    out.xy.push_back(k.pt.x);
    out.xy.push_back(k.pt.y);
  }
  if (!desc.empty()) {
    if (!desc.isContinuous())
      desc = desc.clone();
    if (out.binary) {
      out.desc_u8.reserve(desc.total());
      const uint8_t *p = desc.ptr<uint8_t>();
      for (size_t i = 0; i < desc.total(); ++i)
        out.desc_u8.push_back(p[i]);
    } else {
      cv::Mat d32;
      desc.convertTo(d32, CV_32F);
      out.desc_f32.reserve(d32.total());
      const float *p = d32.ptr<float>();
      for (size_t i = 0; i < d32.total(); ++i)
        out.desc_f32.push_back(p[i]);
    }
  }
  return out;
}

std::unique_ptr<MatchIndex> build_index(const Features &train,
                                        int32_t flann_checks) {
  auto impl = std::make_unique<MatchIndex::Impl>();
  impl->checks = flann_checks;
  impl->binary = train.binary;
  impl->count = train.count;
  impl->train = descriptors_of(train).clone();
  if (!impl->binary && impl->count >= 2 && flann_checks > 0) {
    // FLANN's randomised k-d trees draw from the C library's global generator:
    // seed it under a lock so every index (and so every match) is reproducible.
    static std::mutex seed_lock;
    std::lock_guard<std::mutex> guard(seed_lock);
    cvflann::seed_random(20240611u);
    impl->kd = std::make_unique<cv::flann::Index>(
        impl->train, cv::flann::KDTreeIndexParams(4), cvflann::FLANN_DIST_L2);
  }
  return std::make_unique<MatchIndex>(std::move(impl));
}

rust::Vec<int32_t> match_ratio(const MatchIndex &index, const Features &query,
                               float ratio) {
  rust::Vec<int32_t> out;
  auto &ix = index.impl();
  if (ix.count < 2 || query.count < 1)
    return out;
  if (query.binary != ix.binary || (query.dim != ix.train.cols))
    throw std::invalid_argument(
        "query and index descriptors differ in kind or length");
  cv::Mat q = descriptors_of(query);
  if (ix.binary || !ix.kd) {
    cv::BFMatcher bf(ix.binary ? cv::NORM_HAMMING : cv::NORM_L2);
    std::vector<std::vector<cv::DMatch>> knn;
    bf.knnMatch(q, ix.train, knn, 2);
    for (const auto &m : knn) {
      if (m.size() == 2 && m[0].distance < ratio * m[1].distance) {
        out.push_back(m[0].queryIdx);
        out.push_back(m[0].trainIdx);
      }
    }
    return out;
  }
  cv::Mat indices, dists;
  {
    std::lock_guard<std::mutex> guard(index.lock());
    ix.kd->knnSearch(q, indices, dists, 2, cv::flann::SearchParams(ix.checks));
  }
  // dists are squared L2 distances: compare squared ratio.
  const float r2 = ratio * ratio;
  for (int i = 0; i < indices.rows; ++i) {
    int a = indices.at<int>(i, 0);
    float d0 = dists.at<float>(i, 0), d1 = dists.at<float>(i, 1);
    if (a >= 0 && d0 < r2 * d1) {
      out.push_back(i);
      out.push_back(a);
    }
  }
  return out;
}

Homography find_homography(rust::Slice<const float> src,
                           rust::Slice<const float> dst, double threshold,
                           int32_t max_iters, double confidence,
                           int32_t method) {
  Homography out;
  out.ok = false;
  for (double &v : out.h)
    v = 0.0;
  if (src.size() != dst.size() || src.size() % 2 != 0)
    throw std::invalid_argument("point lists differ in length");
  const int n = int(src.size() / 2);
  if (n < 4)
    return out;
  std::vector<cv::Point2f> a(n), b(n);
  for (int i = 0; i < n; ++i) {
    a[i] = cv::Point2f(src[2 * i], src[2 * i + 1]);
    b[i] = cv::Point2f(dst[2 * i], dst[2 * i + 1]);
  }
  int cv_method = cv::RANSAC;
  if (method == 1)
    cv_method = cv::USAC_MAGSAC;
  else if (method == 2)
    cv_method = cv::LMEDS;
  std::vector<uchar> mask;
  cv::Mat H = cv::findHomography(a, b, cv_method, threshold, mask, max_iters,
                                 confidence);
  if (H.empty())
    return out;
  H.convertTo(H, CV_64F);
  for (int i = 0; i < 9; ++i)
    out.h[i] = H.at<double>(i / 3, i % 3);
  out.inliers.reserve(mask.size());
  for (uchar m : mask)
    out.inliers.push_back(m ? 1 : 0);
  out.ok = true;
  return out;
}

void dis_flow(rust::Slice<const uint8_t> a, rust::Slice<const uint8_t> b,
              int32_t width, int32_t height, const DisParams &p,
              rust::Slice<float> out) {
  if (width <= 0 || height <= 0 || a.size() != size_t(width) * size_t(height) ||
      b.size() != a.size())
    throw std::invalid_argument("flow images differ in size or do not match it");
  if (out.size() != 2 * a.size())
    throw std::invalid_argument("flow output buffer does not match the image size");
  cv::Mat ma(height, width, CV_8U, const_cast<uint8_t *>(a.data()));
  cv::Mat mb(height, width, CV_8U, const_cast<uint8_t *>(b.data()));
  int preset = p.preset == 0   ? cv::DISOpticalFlow::PRESET_ULTRAFAST
               : p.preset == 1 ? cv::DISOpticalFlow::PRESET_FAST
                               : cv::DISOpticalFlow::PRESET_MEDIUM;
  auto dis = cv::DISOpticalFlow::create(preset);
  if (p.finest_scale >= 0)
    dis->setFinestScale(p.finest_scale);
  if (p.patch_size > 0)
    dis->setPatchSize(p.patch_size);
  if (p.patch_stride > 0)
    dis->setPatchStride(p.patch_stride);
  if (p.gradient_descent_iterations > 0)
    dis->setGradientDescentIterations(p.gradient_descent_iterations);
  if (p.variational_refinement_iterations >= 0)
    dis->setVariationalRefinementIterations(
        p.variational_refinement_iterations);
  dis->setUseMeanNormalization(p.use_mean_normalization);
  dis->setUseSpatialPropagation(p.use_spatial_propagation);
  // DIS's coarsest pyramid level for this size (its own formula). When the
  // preset's finest level is coarser than that, OpenCV 4.6 re-picks the levels
  // from the width alone and then reads past pyramid levels shorter than a patch
  // (SIGSEGV on e.g. 80x16 images): lower the finest level to what the size
  // allows instead, and refuse images too small for any level.
  const int psz = dis->getPatchSize();
  const int coarsest =
      std::min(height, width) < psz
          ? -1
          : std::min(int(std::log(std::max(width, height) / (4.0 * psz)) / std::log(2.0) + 0.5),
                     int(std::log(double(std::min(width, height) / psz)) / std::log(2.0)));
  if (coarsest < 0)
    throw std::invalid_argument(
        "image of " + std::to_string(width) + "x" + std::to_string(height) +
        " is too small for optical flow (DIS needs at least " + std::to_string(psz) +
        " pixels in each dimension and " +
        std::to_string(int(std::ceil(psz * std::sqrt(2.0)))) + " in one)");
  if (coarsest < dis->getFinestScale())
    dis->setFinestScale(coarsest);
  cv::Mat flow;
  dis->calc(ma, mb, flow);
  if (flow.type() != CV_32FC2 || flow.rows != height || flow.cols != width)
    throw std::runtime_error("DIS returned a flow field of unexpected shape");
  const size_t row_len = 2 * size_t(width);
  for (int y = 0; y < height; ++y)
    std::memcpy(out.data() + size_t(y) * row_len, flow.ptr<float>(y),
                row_len * sizeof(float));
}

void keep_freed_memory(size_t bytes) {
#if defined(__GLIBC__)
  const size_t cap = INT_MAX / 2;
  const int n = static_cast<int>(std::min(bytes, cap));
  mallopt(M_MMAP_THRESHOLD, n);
  mallopt(M_TRIM_THRESHOLD, 2 * n);
#else
  (void)bytes;
#endif
}

} // namespace lumiprobe
