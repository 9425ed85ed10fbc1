// Example C++ client of lumiprobe's C ABI, built and run by tests/capi.rs:
// opens a scene's probes, asks for the probe at a world position (blended from
// the two nearest), prefilters it and lights one point with it.
//
//   c++ -std=c++17 light_a_point.cpp -I include -L target/release -llumiprobe
//   ./a.out SCENE_DIR X Y Z
//
// Prints "irradiance R G B" (E, not divided by pi, for an upward normal),
// "shaded R G B" (a white rough dielectric seen from above) and "mips N".
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <stdexcept>
#include <string>

#include "lumiprobe.h"

namespace {

// Turns a failed call into an exception carrying lumiprobe's message.
void check(LpStatus s, const char *what) {
    if (s == LP_OK) return;
    char msg[512];
    lp_last_error(msg, sizeof msg);
    throw std::runtime_error(std::string(what) + ": " + msg);
}

struct SetFree { void operator()(LpProbeSet *p) const { lp_probe_set_free(p); } };
struct ImageFree { void operator()(LpImage *p) const { lp_image_free(p); } };
struct PrefilteredFree { void operator()(LpPrefiltered *p) const { lp_prefiltered_free(p); } };

}  // namespace

int main(int argc, char **argv) {
    if (argc != 5) {
        std::fprintf(stderr, "usage: %s SCENE_DIR X Y Z\n", argv[0]);
        return 2;
    }
    try {
        const float at[3] = {std::strtof(argv[2], nullptr), std::strtof(argv[3], nullptr),
                             std::strtof(argv[4], nullptr)};
        LpProbeSet *raw_set = nullptr;
        check(lp_probe_set_open(argv[1], nullptr, &raw_set), "open");
        std::unique_ptr<LpProbeSet, SetFree> set(raw_set);

        LpImage *raw_probe = nullptr;
        check(lp_probe_set_query(set.get(), at, LP_BLEND_INVERSE_DISTANCE, &raw_probe), "query");
        std::unique_ptr<LpImage, ImageFree> probe(raw_probe);

        LpPrefiltered *raw_pf = nullptr;
        check(lp_prefilter(probe.get(), 16, 4, 64, &raw_pf), "prefilter");
        std::unique_ptr<LpPrefiltered, PrefilteredFree> pf(raw_pf);

        // World up is the probe's +y.
        const float up[3] = {0.0f, 1.0f, 0.0f};
        float sh[27], e[3];
        check(lp_prefiltered_sh(pf.get(), sh), "sh");
        check(lp_sh_irradiance(sh, up, e), "irradiance");

        const float white[3] = {1.0f, 1.0f, 1.0f};
        float c[3];
        check(lp_prefiltered_shade(pf.get(), up, up, white, 0.0f, 1.0f, c), "shade");

        // Every face of every mip is readable; out of range gives NULL.
        const uint32_t mips = lp_prefiltered_mip_count(pf.get());
        for (uint32_t m = 0; m < mips; ++m) {
            float rough = 0.0f;
            uint32_t size = 0;
            check(lp_prefiltered_mip_info(pf.get(), m, &rough, &size), "mip info");
            for (uint32_t f = 0; f < 6; ++f) {
                const float *t = lp_prefiltered_face(pf.get(), m, f);
                if (t == nullptr || !(t[0] >= 0.0f)) throw std::runtime_error("bad face");
            }
        }
        if (lp_prefiltered_face(pf.get(), mips, 0) != nullptr) throw std::runtime_error("no NULL");

        std::printf("irradiance %.5f %.5f %.5f\n", e[0], e[1], e[2]);
        std::printf("shaded %.5f %.5f %.5f\n", c[0], c[1], c[2]);
        std::printf("mips %u\n", mips);
    } catch (const std::exception &ex) {
        std::fprintf(stderr, "error: %s\n", ex.what());
        return 1;
    }
    return 0;
}
