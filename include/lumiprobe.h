/*
 * lumiprobe C ABI: HDR light probes for image-based lighting.
 *
 * Link with -llumiprobe (liblumiprobe.so, built by `cargo build --release`).
 * Every declaration here matches one function of src/ffi.rs; tests/capi.rs checks
 * that the two lists agree and compiles and runs a C program against this header.
 *
 * Conventions
 *   - Images are linear RGB, 32-bit float, row-major, 3 interleaved channels.
 *     Equirect panoramas: pixel (col,row) of W x H looks along
 *     phi = ((col+0.5)/W - 0.5) * 2 pi, theta = (0.5 - (row+0.5)/H) * pi,
 *     d = (cos theta sin phi, sin theta, -cos theta cos phi): x right, y up, -z forward.
 *   - Objects are opaque handles; free them with the matching lp_*_free (NULL is ignored).
 *   - Calls that can fail return LpStatus; on failure lp_last_error() gives a message
 *     naming the file involved. Output pointers are written only on success.
 *   - No call aborts the process: internal errors come back as LP_ERR_PANIC.
 *   - Handles may be used from several threads for reading; errors are per thread.
 */
#ifndef LUMIPROBE_H
#define LUMIPROBE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum LpStatus {
    LP_OK = 0,
    LP_ERR_INVALID = 1, /* bad arguments: NULL pointer, size mismatch, unknown name */
    LP_ERR_IO = 2,      /* the operating system refused a read or write */
    LP_ERR_FORMAT = 3,      /* a file's contents are malformed */
    LP_ERR_EXTERNAL = 4,    /* an external library (OpenCV) failed */
    LP_ERR_PANIC = 5,       /* a panic inside the library (a bug); the call was abandoned safely */
    LP_ERR_UNSUPPORTED = 6, /* valid input that is not supported (a pixel type, a compression) */
    LP_ERR_LIMIT = 7,       /* the input asks for more than a limit allows; nothing was allocated */
    LP_ERR_INTERNAL = 8     /* a check inside the library failed on its own data (a bug) */
} LpStatus;

/* The earlier name of LP_ERR_EXTERNAL. */
#define LP_ERR_OPENCV LP_ERR_EXTERNAL

/* An HDR image owned by the library. */
typedef struct LpImage LpImage;

/* Library version, a static string. */
const char *lp_version(void);

/* Copies this thread's last error message (empty after a success) into buf,
 * NUL-terminated and truncated to len; returns the message length without NUL. */
size_t lp_last_error(char *buf, size_t len);

/* Reads an OpenEXR, Radiance .hdr or PFM file. 8-bit files are refused. */
LpStatus lp_image_read(const char *path, LpImage **out);

/* Copies width*height*3 floats from rgb, which holds len floats, into a new
 * image; a len other than width*height*3 is refused (LP_INVALID). */
LpStatus lp_image_from_rgb(const float *rgb, size_t len, uint32_t width, uint32_t height, LpImage **out);

uint32_t lp_image_width(const LpImage *img);
uint32_t lp_image_height(const LpImage *img);

/* width*height*3 floats, valid until lp_image_free. */
const float *lp_image_data(const LpImage *img);

/* Writes .exr (float32), .hdr or .pfm by extension, via a temporary file and rename. */
LpStatus lp_image_write(const LpImage *img, const char *path);

void lp_image_free(LpImage *img);

/* Order-2 spherical harmonics of an equirect probe: 27 floats (9 coefficients x RGB),
 * basis order: 1; y, z, x; xy, yz, 3z^2-1, xz, x^2-y^2. */
LpStatus lp_sh_project(const LpImage *img, float coeffs[27]);

/* Diffuse irradiance E (not divided by pi) at normal n from 27 SH coefficients. */
LpStatus lp_sh_irradiance(const float coeffs[27], const float n[3], float out_rgb[3]);

/* Runs "warp", "flow", "hybrid" or "fusion" with default settings over a scene folder
 * (with poses.json), writing one HDR probe per frame into out_dir. Resumable: a rerun
 * keeps frames made from the same inputs by the same host program (a rebuilt library
 * of the same version does not count as a change; remove the frames to recompute). */
LpStatus lp_run(const char *scene_dir, const char *out_dir, const char *method);

/* ---- Probe sets: probes placed in the world, queried by position ---- */

typedef struct LpProbeSet LpProbeSet;

typedef enum LpBlend {
    LP_BLEND_NEAREST = 0,          /* the nearest probe alone */
    LP_BLEND_INVERSE_DISTANCE = 1  /* the two nearest, weighted by inverse distance */
} LpBlend;

/* Opens the probes of a scene (scene_dir holds poses.json): the per-frame outputs
 * of `lumiprobe run` in run_dir, or, when run_dir is NULL, the scene's own HDR probes. */
LpStatus lp_probe_set_open(const char *scene_dir, const char *run_dir, LpProbeSet **out);

/* Number of probes (0 for NULL). */
uint32_t lp_probe_set_count(const LpProbeSet *set);

/* World position of probe `index` (metres, world z up). */
LpStatus lp_probe_set_position(const LpProbeSet *set, uint32_t index, float xyz[3]);

/* The probe for world position xyz as an equirect image in WORLD orientation:
 * probe axes x = world x, y (up) = world z, -z (panorama centre) = world +y.
 * `blend` is an LpBlend value. Free the image with lp_image_free. */
LpStatus lp_probe_set_query(const LpProbeSet *set, const float xyz[3], uint32_t blend, LpImage **out);

void lp_probe_set_free(LpProbeSet *set);

/* ---- Prefiltered probes for split-sum image-based lighting ---- */

typedef struct LpPrefiltered LpPrefiltered;

/* Prefilters an equirect probe: SH irradiance, a GGX specular cube of mip_count mips
 * (mip i holds roughness i / (mip_count - 1); mip 0 is face_size texels and reproduces
 * the source), `samples` GGX samples per texel, and the split-sum BRDF table.
 * NaN, infinite or negative texels are an error (LP_ERR_INVALID). */
LpStatus lp_prefilter(const LpImage *probe, uint32_t face_size, uint32_t mip_count,
                      uint32_t samples, LpPrefiltered **out);

/* Number of specular mips (0 for NULL). */
uint32_t lp_prefiltered_mip_count(const LpPrefiltered *p);

/* Roughness and face size of specular mip `mip`. */
LpStatus lp_prefiltered_mip_info(const LpPrefiltered *p, uint32_t mip, float *roughness,
                                 uint32_t *face_size);

/* Texels of one cube face of one specular mip: face_size * face_size * 3 floats,
 * row-major, valid until lp_prefiltered_free; NULL when mip or face is out of range.
 * Faces 0..5 look along -z, +x, +z, -x, +y, -y (probe axes). Texel (x, y) of a face
 * of size n looks along N + a R + b D with a = 2 (x + 0.5) / n - 1,
 * b = 2 (y + 0.5) / n - 1 and (N, R, D) = (-z, +x, -y), (+x, +z, -y), (+z, -x, -y),
 * (-x, -z, -y), (+y, +x, -z), (-y, +x, +z). */
const float *lp_prefiltered_face(const LpPrefiltered *p, uint32_t mip, uint32_t face);

/* The 27 SH coefficients (window applied) the irradiance comes from, ordered as
 * lp_sh_project's; pass them to lp_sh_irradiance. */
LpStatus lp_prefiltered_sh(const LpPrefiltered *p, float coeffs[27]);

/* Split-sum shading of one point in the probe's axes: n the unit normal, v the
 * direction from the surface to the eye, glTF metallic-roughness parameters.
 * out_rgb = base_color (1 - metallic) E / pi + prefiltered(reflect, roughness) (F0 A + B),
 * F0 = mix(0.04, base_color, metallic). */
LpStatus lp_prefiltered_shade(const LpPrefiltered *p, const float n[3], const float v[3],
                              const float base_color[3], float metallic, float roughness,
                              float out_rgb[3]);

void lp_prefiltered_free(LpPrefiltered *p);

#ifdef __cplusplus
}
#endif

#endif /* LUMIPROBE_H */
