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
    LP_ERR_FORMAT = 3,  /* malformed or oversized file */
    LP_ERR_OPENCV = 4,  /* the OpenCV layer failed */
    LP_ERR_PANIC = 5    /* internal error; the call was abandoned safely */
} LpStatus;

/* An HDR image owned by the library. */
typedef struct LpImage LpImage;

/* Library version, a static string. */
const char *lp_version(void);

/* Copies this thread's last error message (empty after a success) into buf,
 * NUL-terminated and truncated to len; returns the message length without NUL. */
size_t lp_last_error(char *buf, size_t len);

/* Reads an OpenEXR, Radiance .hdr or PFM file. 8-bit files are refused. */
LpStatus lp_image_read(const char *path, LpImage **out);

/* Copies width*height*3 floats into a new image. */
LpStatus lp_image_from_rgb(const float *rgb, uint32_t width, uint32_t height, LpImage **out);

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
 * (with poses.json), writing one HDR probe per frame into out_dir. Resumable. */
LpStatus lp_run(const char *scene_dir, const char *out_dir, const char *method);

#ifdef __cplusplus
}
#endif

#endif /* LUMIPROBE_H */
