// Boykov-Kolmogorov max-flow and alpha-expansion / alpha-beta swap on grids.
// See maxflow.h for the references; this file follows the published
// descriptions, not any existing implementation.
#include "lumiprobe/cpp/maxflow.h"
#include "lumiprobe/src/cv.rs.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace lumiprobe {

namespace {

bool valid_cap(double c) { return std::isfinite(c) && c >= 0.0; }

std::string num(double v) { return std::to_string(v); }

} // namespace

// ---------------------------------------------------------------------------
// MaxFlow: graph construction
// ---------------------------------------------------------------------------

void MaxFlow::reset(int32_t nodes, size_t edge_hint) {
  if (nodes < 0)
    throw std::invalid_argument("graph cut: negative node count");
  n_ = nodes;
  solved_ = false;
  in_.clear();
  if (edge_hint > in_.capacity())
    in_.reserve(edge_hint);
  src_.assign(size_t(n_), 0.0);
  snk_.assign(size_t(n_), 0.0);
  flow_ = 0.0;
}

void MaxFlow::add_edge(int32_t u, int32_t v, double cap, double rev_cap) {
  if (u < 0 || u >= n_ || v < 0 || v >= n_)
    throw std::invalid_argument("graph cut: edge (" + std::to_string(u) +
                                ", " + std::to_string(v) +
                                ") names a node outside 0.." +
                                std::to_string(n_));
  if (!valid_cap(cap) || !valid_cap(rev_cap))
    throw std::invalid_argument(
        "graph cut: edge (" + std::to_string(u) + ", " + std::to_string(v) +
        ") has capacity " + num(cap) + " / " + num(rev_cap) +
        "; capacities must be finite and >= 0");
  if (u == v || (cap == 0.0 && rev_cap == 0.0))
    return;
  in_.push_back({u, v, cap, rev_cap});
}

void MaxFlow::add_terminal(int32_t u, double source_cap, double sink_cap) {
  if (u < 0 || u >= n_)
    throw std::invalid_argument("graph cut: terminal link of node " +
                                std::to_string(u) + " outside 0.." +
                                std::to_string(n_));
  if (!valid_cap(source_cap) || !valid_cap(sink_cap))
    throw std::invalid_argument(
        "graph cut: terminal capacities " + num(source_cap) + " / " +
        num(sink_cap) + " of node " + std::to_string(u) +
        " must be finite and >= 0");
  src_[size_t(u)] += source_cap;
  snk_[size_t(u)] += sink_cap;
}

// Packs the edge list into compressed rows (all arcs leaving a node are
// contiguous), so the growth and adoption scans walk memory linearly.
void MaxFlow::build() {
  const size_t n = size_t(n_);
  if (in_.size() > size_t(std::numeric_limits<int32_t>::max() / 2))
    throw std::invalid_argument("graph cut: too many edges");
  first_.assign(n + 1, 0);
  for (const InEdge &e : in_) {
    ++first_[size_t(e.u) + 1];
    ++first_[size_t(e.v) + 1];
  }
  for (size_t i = 0; i < n; ++i)
    first_[i + 1] += first_[i];
  arcs_.resize(size_t(first_[n]));
  // Reuse the orphan buffer as the per-node fill position.
  std::vector<int32_t> &pos = orphans_;
  pos.assign(first_.begin(), first_.end() - 1);
  for (const InEdge &e : in_) {
    const int32_t a = pos[size_t(e.u)]++;
    const int32_t b = pos[size_t(e.v)]++;
    arcs_[size_t(a)] = {e.cap, e.v, b};
    arcs_[size_t(b)] = {e.rev, e.u, a};
  }
  pos.clear();

  nodes_.resize(n);
  double total = 0.0;
  for (size_t i = 0; i < n; ++i) {
    // Flow straight from s to t through the node saturates the smaller link.
    const double s = src_[i], t = snk_[i];
    total += s;
    flow_ += std::min(s, t);
    nodes_[i].tr = s - t;
  }
  if (!std::isfinite(total))
    throw std::invalid_argument(
        "graph cut: the source capacities overflow a double");
}

// ---------------------------------------------------------------------------
// MaxFlow: Boykov-Kolmogorov search trees
// ---------------------------------------------------------------------------

void MaxFlow::activate(int32_t u) {
  Node &nu = nodes_[size_t(u)];
  if (nu.queued)
    return;
  nu.queued = 1;
  nu.next = -1;
  if (q_tail_ >= 0)
    nodes_[size_t(q_tail_)].next = u;
  else
    q_head_ = u;
  q_tail_ = u;
}

// Pops active nodes until one still in a tree turns up (nodes freed while
// queued are dropped lazily here).
int32_t MaxFlow::next_active() {
  while (q_head_ >= 0) {
    const int32_t u = q_head_;
    Node &nu = nodes_[size_t(u)];
    q_head_ = nu.next;
    if (q_head_ < 0)
      q_tail_ = -1;
    nu.next = -1;
    nu.queued = 0;
    if (nu.parent != FREE)
      return u;
  }
  return -1;
}

void MaxFlow::make_orphan(int32_t u) {
  nodes_[size_t(u)].parent = ORPHAN;
  orphans_.push_back(u);
}

void MaxFlow::bump_time() {
  if (time_ == std::numeric_limits<int32_t>::max()) {
    for (Node &nd : nodes_)
      nd.ts = 0;
    time_ = 0;
  }
  ++time_;
}

// Pushes the bottleneck along s -> ... -> tail(hit) -> head(hit) -> ... -> t,
// where `hit` is a residual arc from an S node to a T node. Nodes whose link to
// their parent saturates become orphans.
void MaxFlow::augment(int32_t hit) {
  Arc &mid = arcs_[size_t(hit)];
  const int32_t s_end = arcs_[size_t(mid.sister)].head;
  const int32_t t_end = mid.head;

  double b = mid.rcap;
  int32_t x = s_end;
  for (;;) {
    const int32_t a = nodes_[size_t(x)].parent;
    if (a == TERMINAL)
      break;
    b = std::min(b, arcs_[size_t(arcs_[size_t(a)].sister)].rcap);
    x = arcs_[size_t(a)].head;
  }
  b = std::min(b, nodes_[size_t(x)].tr);
  x = t_end;
  for (;;) {
    const int32_t a = nodes_[size_t(x)].parent;
    if (a == TERMINAL)
      break;
    b = std::min(b, arcs_[size_t(a)].rcap);
    x = arcs_[size_t(a)].head;
  }
  b = std::min(b, -nodes_[size_t(x)].tr);

  mid.rcap -= b;
  arcs_[size_t(mid.sister)].rcap += b;

  // Source side: the arcs parent -> child lose capacity.
  x = s_end;
  for (;;) {
    Node &nx = nodes_[size_t(x)];
    const int32_t a = nx.parent;
    if (a == TERMINAL) {
      nx.tr -= b;
      if (nx.tr <= 0.0) {
        nx.tr = 0.0;
        make_orphan(x);
      }
      break;
    }
    Arc &up = arcs_[size_t(a)];
    Arc &down = arcs_[size_t(up.sister)];
    up.rcap += b;
    down.rcap -= b;
    const int32_t parent = up.head;
    if (down.rcap <= 0.0) {
      down.rcap = 0.0;
      make_orphan(x);
    }
    x = parent;
  }
  // Sink side: the arcs child -> parent lose capacity.
  x = t_end;
  for (;;) {
    Node &nx = nodes_[size_t(x)];
    const int32_t a = nx.parent;
    if (a == TERMINAL) {
      nx.tr += b;
      if (nx.tr >= 0.0) {
        nx.tr = 0.0;
        make_orphan(x);
      }
      break;
    }
    Arc &up = arcs_[size_t(a)];
    up.rcap -= b;
    arcs_[size_t(up.sister)].rcap += b;
    const int32_t parent = up.head;
    if (up.rcap <= 0.0) {
      up.rcap = 0.0;
      make_orphan(x);
    }
    x = parent;
  }
  flow_ += b;
}

// Finds orphan u a new parent in its own tree whose chain reaches the terminal
// (preferring the shortest such chain); failing that u becomes free, its
// children become orphans and neighbours that could regrow into u turn active.
void MaxFlow::adopt(int32_t u) {
  Node &nu = nodes_[size_t(u)];
  const uint8_t tree = nu.sink;
  if ((!tree && nu.tr > 0.0) || (tree && nu.tr < 0.0)) {
    nu.parent = TERMINAL;
    nu.ts = time_;
    nu.dist = 1;
    return;
  }
  constexpr int32_t INF = std::numeric_limits<int32_t>::max();
  const int32_t begin = first_[size_t(u)], end = first_[size_t(u) + 1];
  int32_t best = FREE, best_d = INF;
  for (int32_t a = begin; a < end; ++a) {
    const Arc &arc = arcs_[size_t(a)];
    // S: needs residual q -> u; T: needs residual u -> q.
    const double r = tree ? arc.rcap : arcs_[size_t(arc.sister)].rcap;
    if (r <= 0.0)
      continue;
    const int32_t q = arc.head;
    const Node &nq = nodes_[size_t(q)];
    if (nq.parent == FREE || nq.sink != tree)
      continue;
    // Walk towards the root; a cached distance from this round ends the walk.
    int32_t d = 0;
    int32_t x = q;
    for (;;) {
      Node &nx = nodes_[size_t(x)];
      if (nx.ts == time_) {
        d += nx.dist;
        break;
      }
      const int32_t pa = nx.parent;
      ++d;
      if (pa == TERMINAL) {
        nx.ts = time_;
        nx.dist = 1;
        break;
      }
      if (pa < 0) { // ORPHAN (FREE cannot occur inside a tree)
        d = INF;
        break;
      }
      x = arcs_[size_t(pa)].head;
    }
    if (d == INF)
      continue;
    if (d < best_d) {
      best = a;
      best_d = d;
    }
    // Cache the distances along the walked chain for later orphans.
    for (x = q; nodes_[size_t(x)].ts != time_;
         x = arcs_[size_t(nodes_[size_t(x)].parent)].head) {
      nodes_[size_t(x)].ts = time_;
      nodes_[size_t(x)].dist = d--;
    }
  }
  if (best != FREE) {
    nu.parent = best;
    nu.ts = time_;
    nu.dist = best_d + 1;
    return;
  }
  nu.parent = FREE;
  for (int32_t a = begin; a < end; ++a) {
    const Arc &arc = arcs_[size_t(a)];
    const int32_t q = arc.head;
    Node &nq = nodes_[size_t(q)];
    if (nq.parent == FREE || nq.sink != tree)
      continue;
    const double r = tree ? arc.rcap : arcs_[size_t(arc.sister)].rcap;
    if (r > 0.0)
      activate(q);
    if (nq.parent >= 0 && arcs_[size_t(nq.parent)].head == u)
      make_orphan(q);
  }
}

double MaxFlow::solve() {
  if (solved_)
    throw std::logic_error("graph cut: solve() called twice on one graph");
  build();
  q_head_ = q_tail_ = -1;
  orphans_.clear();
  time_ = 0;
  for (int32_t u = 0; u < n_; ++u) {
    Node &nu = nodes_[size_t(u)];
    nu.next = -1;
    nu.queued = 0;
    nu.ts = 0;
    nu.dist = 1;
    nu.sink = 0;
    if (nu.tr > 0.0) {
      nu.parent = TERMINAL;
      activate(u);
    } else if (nu.tr < 0.0) {
      nu.parent = TERMINAL;
      nu.sink = 1;
      activate(u);
    } else {
      nu.parent = FREE;
    }
  }

  int32_t current = -1; // node kept active after an augmentation through it
  for (;;) {
    int32_t p = current;
    current = -1;
    if (p < 0 || nodes_[size_t(p)].parent == FREE) {
      p = next_active();
      if (p < 0)
        break;
    }
    // Growth: extend p's tree by its free neighbours until the trees touch.
    const Node &np = nodes_[size_t(p)];
    int32_t hit = -1;
    const int32_t end = first_[size_t(p) + 1];
    if (!np.sink) {
      for (int32_t a = first_[size_t(p)]; a < end; ++a) {
        const Arc &arc = arcs_[size_t(a)];
        if (arc.rcap <= 0.0)
          continue;
        Node &nq = nodes_[size_t(arc.head)];
        if (nq.parent == FREE) {
          nq.sink = 0;
          nq.parent = arc.sister;
          nq.ts = np.ts;
          nq.dist = np.dist + 1;
          activate(arc.head);
        } else if (nq.sink) {
          hit = a;
          break;
        }
      }
    } else {
      for (int32_t a = first_[size_t(p)]; a < end; ++a) {
        const Arc &arc = arcs_[size_t(a)];
        if (arcs_[size_t(arc.sister)].rcap <= 0.0)
          continue;
        Node &nq = nodes_[size_t(arc.head)];
        if (nq.parent == FREE) {
          nq.sink = 1;
          nq.parent = arc.sister;
          nq.ts = np.ts;
          nq.dist = np.dist + 1;
          activate(arc.head);
        } else if (!nq.sink) {
          hit = arc.sister;
          break;
        }
      }
    }
    if (hit < 0)
      continue; // p is exhausted and turns passive
    // Augmentation, then adoption; both trees are kept for the next round.
    current = p;
    bump_time();
    augment(hit);
    for (size_t i = 0; i < orphans_.size(); ++i)
      adopt(orphans_[i]);
    orphans_.clear();
  }
  solved_ = true;
  return flow_;
}

bool MaxFlow::source_side(int32_t u) const {
  const Node &nu = nodes_[size_t(u)];
  return solved_ && nu.parent != FREE && !nu.sink;
}

bool MaxFlow::sink_tree(int32_t u) const {
  const Node &nu = nodes_[size_t(u)];
  return solved_ && nu.parent != FREE && nu.sink;
}

GcFlow gc_max_flow(uint32_t nodes, rust::Slice<const GcEdge> edges,
                   rust::Slice<const double> terminals) {
  if (nodes > uint32_t(std::numeric_limits<int32_t>::max()))
    throw std::invalid_argument("graph cut: too many nodes");
  if (terminals.size() != 2 * size_t(nodes))
    throw std::invalid_argument(
        "graph cut: need a (source, sink) capacity pair per node");
  MaxFlow mf;
  mf.reset(int32_t(nodes), edges.size());
  for (const GcEdge &e : edges) {
    if (e.from >= nodes || e.to >= nodes)
      throw std::invalid_argument("graph cut: edge (" + std::to_string(e.from) +
                                  ", " + std::to_string(e.to) +
                                  ") names a node outside 0.." +
                                  std::to_string(nodes));
    mf.add_edge(int32_t(e.from), int32_t(e.to), e.cap, e.rev_cap);
  }
  for (uint32_t u = 0; u < nodes; ++u)
    mf.add_terminal(int32_t(u), terminals[2 * size_t(u)],
                    terminals[2 * size_t(u) + 1]);
  GcFlow out;
  out.flow = mf.solve();
  out.side.reserve(nodes);
  for (uint32_t u = 0; u < nodes; ++u)
    out.side.push_back(mf.source_side(int32_t(u))
                           ? 1
                           : (mf.sink_tree(int32_t(u)) ? 2 : 0));
  return out;
}

// ---------------------------------------------------------------------------
// Grid energies: E(f) = sum_p D_p(f_p) + lambda sum_{p~q} V_pq(f_p, f_q),
// V_pq(a, b) = |F_a(p) - F_b(p)| + |F_a(q) - F_b(q)| (the seam cost).
// ---------------------------------------------------------------------------

namespace {

class Grid {
public:
  Grid(const GcGridParams &prm, rust::Slice<const float> data,
       rust::Slice<const float> features)
      : W_(prm.width), H_(prm.height), L_(prm.labels), C_(prm.channels),
        N_(size_t(prm.width) * size_t(prm.height)), lambda_(prm.lambda),
        cap_(prm.seam_cap), wrap_(prm.wrap_x && prm.width >= 3),
        data_(data.data()), feat_(features.data()) {
    if (W_ == 0 || H_ == 0)
      throw std::invalid_argument("graph cut: empty grid");
    if (N_ > (size_t(1) << 28))
      throw std::invalid_argument("graph cut: grid too large");
    if (L_ < 1 || L_ > 255)
      throw std::invalid_argument("graph cut: need 1..255 labels, got " +
                                  std::to_string(L_));
    if (data.size() != N_ * L_)
      throw std::invalid_argument("graph cut: data costs have " +
                                  std::to_string(data.size()) +
                                  " values, expected width*height*labels = " +
                                  std::to_string(N_ * L_));
    if (features.size() != N_ * L_ * C_)
      throw std::invalid_argument(
          "graph cut: features have " + std::to_string(features.size()) +
          " values, expected width*height*labels*channels = " +
          std::to_string(N_ * L_ * C_));
    if (!std::isfinite(lambda_) || lambda_ < 0.0)
      throw std::invalid_argument("graph cut: lambda must be finite and >= 0");
    if (!std::isfinite(cap_) || cap_ <= 0.0)
      throw std::invalid_argument("graph cut: seam cap must be finite and > 0");
    for (size_t i = 0; i < N_ * L_; ++i) {
      const float d = data_[i];
      if (!std::isfinite(d) || d < 0.0f) {
        const size_t p = i / L_;
        throw std::invalid_argument(
            "graph cut: data cost " + num(d) + " of label " +
            std::to_string(i % L_) + " at pixel (" + std::to_string(p % W_) +
            ", " + std::to_string(p / W_) + ") must be finite and >= 0");
      }
    }
    // Cache the per-pixel label distances when that fits in 256 MiB.
    P_ = size_t(L_) * (L_ - 1) / 2;
    pair_.assign(size_t(L_) * L_, 0);
    for (uint32_t a = 0, k = 0; a < L_; ++a)
      for (uint32_t b = a + 1; b < L_; ++b, ++k)
        pair_[a * L_ + b] = pair_[b * L_ + a] = k;
    if (P_ > 0 && N_ * P_ <= (size_t(32) << 20)) {
      table_.resize(N_ * P_);
      for (size_t p = 0; p < N_; ++p)
        for (uint32_t a = 0; a < L_; ++a)
          for (uint32_t b = a + 1; b < L_; ++b)
            table_[p * P_ + pair_[a * L_ + b]] = compute_dist(p, a, b);
    }
  }

  size_t pixels() const { return N_; }
  uint32_t labels() const { return L_; }
  double lambda() const { return lambda_; }
  double D(size_t p, uint32_t l) const { return double(data_[p * L_ + l]); }

  // |F_a(p) - F_b(p)|, capped; non-finite features count as the cap.
  double dist(size_t p, uint32_t a, uint32_t b) const {
    if (a == b)
      return 0.0;
    if (!table_.empty())
      return table_[p * P_ + pair_[a * L_ + b]];
    return compute_dist(p, a, b);
  }
  double V(size_t p, size_t q, uint32_t a, uint32_t b) const {
    if (a == b)
      return 0.0;
    return dist(p, a, b) + dist(q, a, b);
  }

  // Calls f(p, q) for every 4-neighbour pair, right neighbours first then
  // down, row by row (the order the Rust energy uses too).
  template <class F> void for_each_edge(F &&f) const {
    for (size_t y = 0; y < H_; ++y) {
      const size_t row = y * W_;
      for (size_t x = 0; x < W_; ++x) {
        const size_t p = row + x;
        if (x + 1 < W_)
          f(p, p + 1);
        else if (wrap_)
          f(p, row);
        if (y + 1 < H_)
          f(p, p + W_);
      }
    }
  }

  void energy(const std::vector<uint8_t> &f, double &data,
              double &smooth) const {
    data = 0.0;
    for (size_t p = 0; p < N_; ++p)
      data += D(p, f[p]);
    double s = 0.0;
    for_each_edge([&](size_t p, size_t q) { s += V(p, q, f[p], f[q]); });
    smooth = lambda_ * s;
  }

private:
  double compute_dist(size_t p, uint32_t a, uint32_t b) const {
    const float *fa = feat_ + (p * L_ + a) * C_;
    const float *fb = feat_ + (p * L_ + b) * C_;
    double s = 0.0;
    for (size_t c = 0; c < C_; ++c) {
      const double u = fa[c], v = fb[c];
      if (!std::isfinite(u) || !std::isfinite(v))
        return cap_;
      const double d = u - v;
      s += d * d;
    }
    const double r = std::sqrt(s);
    return r < cap_ ? r : cap_;
  }

  size_t W_, H_;
  uint32_t L_;
  size_t C_, N_;
  double lambda_, cap_;
  bool wrap_;
  const float *data_;
  const float *feat_;
  size_t P_ = 0;
  std::vector<uint32_t> pair_;
  std::vector<double> table_;
};

class Optimizer {
public:
  Optimizer(const Grid &g, std::vector<uint8_t> labels, bool check)
      : g_(g), f_(std::move(labels)), check_(check) {
    g_.energy(f_, data_e_, smooth_e_);
    node_.resize(g_.pixels());
  }

  double energy() const { return data_e_ + smooth_e_; }
  double data_energy() const { return data_e_; }
  double smooth_energy() const { return smooth_e_; }
  const std::vector<uint8_t> &labels() const { return f_; }

  // One expansion move: every pixel may keep its label (x = 0, source side)
  // or switch to alpha (x = 1, sink side). Returns true if accepted.
  bool expand(uint8_t alpha) {
    const size_t N = g_.pixels();
    int32_t k = 0;
    for (size_t p = 0; p < N; ++p)
      node_[p] = f_[p] == alpha ? -1 : k++;
    if (k == 0)
      return false;
    start(k);
    for (size_t p = 0; p < N; ++p) {
      const int32_t i = node_[p];
      if (i >= 0) {
        t0_[size_t(i)] += g_.D(p, f_[p]);
        t1_[size_t(i)] += g_.D(p, alpha);
      }
    }
    const double lam = g_.lambda();
    g_.for_each_edge([&](size_t p, size_t q) {
      const int32_t ip = node_[p], iq = node_[q];
      if (ip < 0 && iq < 0)
        return;
      if (ip < 0) { // p is alpha: q pays V(alpha, f_q) unless it switches
        t0_[size_t(iq)] += lam * g_.V(p, q, alpha, f_[q]);
        return;
      }
      if (iq < 0) {
        t0_[size_t(ip)] += lam * g_.V(p, q, f_[p], alpha);
        return;
      }
      const double A = lam * g_.V(p, q, f_[p], f_[q]);
      const double B = lam * g_.V(p, q, f_[p], alpha);
      const double C = lam * g_.V(p, q, alpha, f_[q]);
      pairwise(ip, iq, A, B, C, 0.0);
    });
    finish(k);
    cand_ = f_;
    for (size_t p = 0; p < N; ++p)
      if (node_[p] >= 0 && mf_.sink_tree(node_[p]))
        cand_[p] = alpha;
    return accept();
  }

  // One swap move: pixels labelled alpha or beta choose between them
  // (x = 0 alpha, source side; x = 1 beta, sink side).
  bool swap(uint8_t alpha, uint8_t beta) {
    const size_t N = g_.pixels();
    int32_t k = 0;
    for (size_t p = 0; p < N; ++p)
      node_[p] = (f_[p] == alpha || f_[p] == beta) ? k++ : -1;
    if (k == 0)
      return false;
    start(k);
    for (size_t p = 0; p < N; ++p) {
      const int32_t i = node_[p];
      if (i >= 0) {
        t0_[size_t(i)] += g_.D(p, alpha);
        t1_[size_t(i)] += g_.D(p, beta);
      }
    }
    const double lam = g_.lambda();
    g_.for_each_edge([&](size_t p, size_t q) {
      const int32_t ip = node_[p], iq = node_[q];
      if (ip < 0 && iq < 0)
        return;
      if (ip >= 0 && iq >= 0) {
        // E(0,0) = E(1,1) = 0: a plain arc pair.
        const double B = lam * g_.V(p, q, alpha, beta);
        const double C = lam * g_.V(p, q, beta, alpha);
        if (B > 0.0 || C > 0.0)
          mf_.add_edge(ip, iq, B, C);
      } else if (ip >= 0) {
        t0_[size_t(ip)] += lam * g_.V(p, q, alpha, f_[q]);
        t1_[size_t(ip)] += lam * g_.V(p, q, beta, f_[q]);
      } else {
        t0_[size_t(iq)] += lam * g_.V(p, q, f_[p], alpha);
        t1_[size_t(iq)] += lam * g_.V(p, q, f_[p], beta);
      }
    });
    finish(k);
    cand_ = f_;
    for (size_t p = 0; p < N; ++p)
      if (node_[p] >= 0)
        cand_[p] = mf_.sink_tree(node_[p]) ? beta : alpha;
    return accept();
  }

private:
  void start(int32_t k) {
    mf_.reset(k, 2 * size_t(k));
    t0_.assign(size_t(k), 0.0);
    t1_.assign(size_t(k), 0.0);
  }

  // Kolmogorov & Zabih's decomposition of a submodular term E(x_p, x_q) with
  // E(0,0) = A, E(0,1) = B, E(1,0) = C, E(1,1) = D:
  //   A + (C - A) x_p + (D - C) x_q + (B + C - A - D) (1 - x_p) x_q.
  void pairwise(int32_t p, int32_t q, double A, double B, double C, double D) {
    unary(p, C - A);
    unary(q, D - C);
    // >= 0 for a metric V; rounding may leave a negative ulp-sized residue,
    // which the energy check in accept() makes harmless.
    const double w = B + C - A - D;
    if (w > 0.0)
      mf_.add_edge(p, q, w, 0.0);
  }
  void unary(int32_t i, double k) {
    if (k > 0.0)
      t1_[size_t(i)] += k;
    else
      t0_[size_t(i)] -= k;
  }

  void finish(int32_t k) {
    // x = 0 is the source side, so its cost is the cut link to the sink.
    for (int32_t i = 0; i < k; ++i)
      mf_.add_terminal(i, t1_[size_t(i)], t0_[size_t(i)]);
    mf_.solve();
  }

  // Keeps the candidate labelling only if it lowers the exact energy: the
  // graph guarantees that up to rounding, and this makes it unconditional.
  bool accept() {
    double d, s;
    g_.energy(cand_, d, s);
    const double before = energy(), after = d + s;
    if (check_ && after > before + 1e-9 * std::max(1.0, std::fabs(before)))
      throw std::logic_error("graph cut internal error: a move raised the "
                             "energy from " +
                             num(before) + " to " + num(after));
    if (!(after < before))
      return false;
    f_.swap(cand_);
    data_e_ = d;
    smooth_e_ = s;
    return true;
  }

  const Grid &g_;
  std::vector<uint8_t> f_, cand_;
  std::vector<int32_t> node_;
  std::vector<double> t0_, t1_;
  MaxFlow mf_;
  double data_e_ = 0.0, smooth_e_ = 0.0;
  bool check_;
};

} // namespace

GcGridResult gc_optimize_grid(const GcGridParams &params,
                              rust::Slice<const float> data,
                              rust::Slice<const float> features,
                              rust::Slice<const uint8_t> init) {
  const Grid g(params, data, features);
  const size_t N = g.pixels();
  if (init.size() != N)
    throw std::invalid_argument("graph cut: initial labelling has " +
                                std::to_string(init.size()) +
                                " entries, expected " + std::to_string(N));
  std::vector<uint8_t> f(init.begin(), init.end());
  for (size_t p = 0; p < N; ++p)
    if (f[p] >= g.labels())
      throw std::invalid_argument(
          "graph cut: initial label " + std::to_string(f[p]) + " at pixel " +
          std::to_string(p) + " is not below " + std::to_string(g.labels()));

  Optimizer opt(g, std::move(f), params.check);
  const uint32_t L = g.labels();
  GcGridResult out;
  out.cycles = 0;
  for (uint32_t cycle = 0; cycle < params.max_cycles; ++cycle) {
    bool improved = false;
    if (params.swap) {
      for (uint32_t a = 0; a < L; ++a)
        for (uint32_t b = a + 1; b < L; ++b)
          improved |= opt.swap(uint8_t(a), uint8_t(b));
    } else {
      for (uint32_t a = 0; a < L; ++a)
        improved |= opt.expand(uint8_t(a));
    }
    ++out.cycles;
    out.history.push_back(opt.energy());
    if (!improved)
      break;
  }
  out.data_energy = opt.data_energy();
  out.smooth_energy = opt.smooth_energy();
  out.labels.reserve(N);
  for (uint8_t l : opt.labels())
    out.labels.push_back(l);
  return out;
}

} // namespace lumiprobe
