// Graph cuts for lumiprobe's flow method (Gupta et al. 2009 style fusion of
// warped HDR probes and the SDR frame):
//
//  * MaxFlow: the Boykov-Kolmogorov augmenting-path max-flow / min-cut
//    algorithm (Boykov & Kolmogorov 2004, "An experimental comparison of
//    min-cut/max-flow algorithms for energy minimization in vision", PAMI 26(9)),
//    written from the paper's description: two search trees S and T grown from
//    the terminals, augmentation along the path where they touch, adoption of
//    orphans, and reuse of both trees across augmentations.
//  * Grid energy minimisation with alpha-expansion and alpha-beta swap moves
//    (Boykov, Veksler & Zabih 2001, "Fast approximate energy minimization via
//    graph cuts", PAMI 23(11)); pairwise terms of each binary move are built by
//    the decomposition of submodular two-variable terms (Kolmogorov & Zabih 2004,
//    "What energy functions can be minimized via graph cuts?", PAMI 26(2)).
//
// Capacities are doubles: costs arrive as floats, so sums of up to a few
// million of them stay exact to far below one float ulp, and the residual
// arithmetic a - b == 0 holds exactly iff a == b (gradual underflow), so
// saturation tests never drift. All inputs are validated: a bad index or a
// non-finite or negative capacity throws std::invalid_argument (a Rust Err).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "rust/cxx.h"

namespace lumiprobe {

struct GcEdge;
struct GcFlow;
struct GcGridParams;
struct GcGridResult;

// Max-flow / min-cut on a general directed graph with terminal links.
// Usage: reset(n); add_edge(...)/add_terminal(...) any number of times;
// solve(); source_side(u). Buffers are kept across reset() calls, so a
// sequence of moves on one grid allocates only once.
class MaxFlow {
public:
  // Forgets the previous graph and starts one with `nodes` nodes and no edges;
  // `edge_hint` pre-reserves room for that many edge pairs.
  void reset(int32_t nodes, size_t edge_hint = 0);
  // Adds the arc pair u->v with capacity `cap` and v->u with `rev_cap`.
  // Self-loops and pairs with both capacities zero are dropped (they never
  // cross a cut).
  void add_edge(int32_t u, int32_t v, double cap, double rev_cap);
  // Adds `source_cap` to the link s->u and `sink_cap` to u->t.
  void add_terminal(int32_t u, double source_cap, double sink_cap);
  // Computes the maximum flow (= minimum cut capacity). Call once per graph.
  double solve();
  // After solve(): true if u is on the source side of the minimum cut. The
  // source side is the set of nodes reachable from s in the residual graph
  // (the smallest minimum-cut source set).
  bool source_side(int32_t u) const;
  // After solve(): true if u is in the final sink tree, i.e. can still reach t
  // in the residual graph. Nodes in neither tree may go to either side: both
  // "S tree" and "not T tree" are minimum cuts.
  bool sink_tree(int32_t u) const;
  int32_t node_count() const { return n_; }

private:
  struct InEdge {
    int32_t u, v;
    double cap, rev;
  };
  struct Arc {
    double rcap;    // residual capacity of this arc
    int32_t head;   // node the arc points to
    int32_t sister; // the reverse arc
  };
  struct Node {
    double tr;          // residual terminal capacity: > 0 from s, < 0 to t
    int32_t parent;     // arc from this node to its tree parent, or a tag
    int32_t next;       // next node in the active FIFO (-1 = end)
    int32_t ts;         // timestamp of `dist`
    int32_t dist;       // distance to the terminal along the tree
    uint8_t sink;       // tree of the node when parent != FREE: 0 = S, 1 = T
    uint8_t queued;     // 1 while in the active FIFO
  };
  static constexpr int32_t TERMINAL = -1; // parent is the terminal itself
  static constexpr int32_t ORPHAN = -2;   // lost its parent, being adopted
  static constexpr int32_t FREE = -3;     // in neither tree

  void build();
  void activate(int32_t u);
  int32_t next_active();
  void augment(int32_t arc);
  void adopt(int32_t u);
  void make_orphan(int32_t u);
  void bump_time();

  int32_t n_ = 0;
  bool solved_ = false;
  std::vector<InEdge> in_;
  std::vector<double> src_, snk_;
  std::vector<int32_t> first_; // CSR offsets, n + 1
  std::vector<Arc> arcs_;
  std::vector<Node> nodes_;
  std::vector<int32_t> orphans_;
  size_t orphan_head_ = 0;
  int32_t q_head_ = -1, q_tail_ = -1;
  int32_t time_ = 0;
  double flow_ = 0.0;
};

// Bridge entry points (see src/cv.rs, "graph cut" section).
GcFlow gc_max_flow(uint32_t nodes, rust::Slice<const GcEdge> edges,
                   rust::Slice<const double> terminals);
GcGridResult gc_optimize_grid(const GcGridParams &params,
                              rust::Slice<const float> data,
                              rust::Slice<const float> features,
                              rust::Slice<const uint8_t> init);

} // namespace lumiprobe
