/*
 * lightmapper_cornell.c: a peer benchmark. Bakes Radiant's builtin Cornell box with
 * lightmapper.h (https://github.com/ands/lightmapper, Andreas Mantler: a single-header GPU
 * hemicube light-map baker on OpenGL) on a headless Mesa context (llvmpipe), and prints each
 * surface's area-weighted mean radiosity as CSV, in Radiant's units, for
 * tools/surface_error.py to compare with the Mitsuba reference.
 *
 * lightmapper.h is NOT part of this repository. Its header says it is in the public domain
 * (with a perpetual licence to copy and modify where that is not recognised). Get it with
 *     git clone https://github.com/ands/lightmapper /tmp/lightmapper
 * (or any copy of lightmapper.h) and build through tools/lightmapper_cornell.sh HEADER_DIR,
 * which compiles this file with -I HEADER_DIR.
 *
 * What it does:
 *  - a GL 3.3 core context without a window or display server: EGL on Mesa's surfaceless
 *    platform (EGL_PLATFORM_SURFACELESS_MESA), else EGL's device platform, else the default
 *    display with a 1x1 pbuffer;
 *  - the 19 quads of assets/cornell_box.gltf (Cornell's published data in metres, `bitterli`
 *    RGB reflectances, the light's radiance (17, 12, 4)), two triangles per quad as there;
 *  - an atlas: each quad gets its own rectangular chart (the quad in its own plane at DENSITY
 *    texels per metre) with one texel of empty padding, packed in shelves;
 *  - BOUNCES gathers with lightmapper.h: gather k draws the scene onto lightmapper's hemicubes
 *    coloured E + rho * H_{k-1} (H_0 = 0: the first gather sees the emitter only), and
 *    lightmapper writes H_k into the light map; one-sided surfaces: a back face is drawn black;
 *  - the per-surface means: sum over the chart's texels of (texel area inside the quad) *
 *    (E + rho * H) / quad area, the texel value constant over the texel.
 *
 * Units. Radiant's H is the incident radiance averaged with the cosine (irradiance / pi), in
 * emissive units, and a surface shows B = E + rho * H. lightmapper.h returns
 *     sum_p L_p w(cos_p) dw_p / sum_p dw_p
 * over the hemicube pixels p (dw_p their solid angle; w the hemisphere weight function, 1 by
 * default): by default the *solid-angle* average of the radiance, not the cosine-weighted one.
 * We set w(c) = k c with k = sum dw / sum dw cos over the same pixels (k ~ 2) so that the
 * result is the cosine-weighted mean, H itself: a surface that sees an emitter of radiance L
 * over its whole hemisphere gets H = L (as with the default weights).
 *
 * Output: stdout is CSV `name,r,g,b,area_m2,emitter` (one row per quad, radiosity in emissive
 * units); stderr has the settings, the texel counts and the timings.
 *
 * Usage: lightmapper_cornell [--density TEXELS_PER_M | --texels N] [--bounces N]
 *        [--hemisphere 16|32|64|128|256|512] [--interpolation-passes 0..8]
 *        [--interpolation-threshold T] [--no-interpolation] [--znear M] [--zfar M]
 *        [--distance-modifier X]
 * Defaults: --texels 5080 (the density that gives the quads 5,080 texels of area, 51.4 per
 * metre), 12 bounces, hemisphere 64 (lightmapper's example), interpolation passes 4 and
 * threshold 0.01 (lmCreate's documented defaults; the threshold is absolute, in H's units),
 * zNear 0.001 m, zFar 10 m, distance modifier 0, a black background (nothing outside the box).
 *
 * Notes on lightmapper.h seen here: it has no notion of an emitter (the light is whatever the
 * caller draws, here the light quad with its radiance); it gathers at every texel a triangle
 * touches, at the centroid of the covered part, and a texel on a quad's diagonal is gathered
 * once per triangle (the first result is kept); each hemicube is turned by a pattern plus
 * rand() jitter, so successive bounces differ by about 1 % per texel even when converged.
 */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define EGL_EGLEXT_PROTOTYPES
#include <EGL/egl.h>
#include <EGL/eglext.h>
#define GL_GLEXT_PROTOTYPES
#define GL_GLCOREARB_PROTOTYPES
#include <GL/glcorearb.h>

#define LIGHTMAPPER_IMPLEMENTATION
#include "lightmapper.h"

/* ---- the scene: assets/cornell_box.gltf (tools/make_cornell_gltf.py), metres ---- */

typedef struct {
    const char *name;
    int material;    /* index into MATERIALS */
    double v[4][3];  /* counter-clockwise seen from the lit side */
} Quad;

typedef struct {
    const char *name;
    double rho[3];      /* reflectance (glTF baseColorFactor) */
    double emission[3]; /* emitted radiance */
} Material;

static const Material MATERIALS[] = {
    {"white", {0.725, 0.71, 0.68}, {0, 0, 0}},
    {"red", {0.63, 0.065, 0.05}, {0, 0, 0}},
    {"green", {0.14, 0.45, 0.091}, {0, 0, 0}},
    {"light", {0.78, 0.78, 0.78}, {17.0, 12.0, 4.0}},
};
enum { WHITE, RED, GREEN, LIGHT };

#define MM(x, y, z) {(x) / 1000.0, (y) / 1000.0, (z) / 1000.0}
static const Quad QUADS[] = {
    {"floor", WHITE, {MM(552.8, 0, 0), MM(0, 0, 0), MM(0, 0, 559.2), MM(549.6, 0, 559.2)}},
    {"ceiling_front", WHITE, {MM(556, 548.8, 0), MM(556, 548.8, 227), MM(0, 548.8, 227), MM(0, 548.8, 0)}},
    {"ceiling_back", WHITE, {MM(556, 548.8, 332), MM(556, 548.8, 559.2), MM(0, 548.8, 559.2), MM(0, 548.8, 332)}},
    {"ceiling_left", WHITE, {MM(556, 548.8, 227), MM(556, 548.8, 332), MM(343, 548.8, 332), MM(343, 548.8, 227)}},
    {"ceiling_right", WHITE, {MM(213, 548.8, 227), MM(213, 548.8, 332), MM(0, 548.8, 332), MM(0, 548.8, 227)}},
    {"back_wall", WHITE, {MM(549.6, 0, 559.2), MM(0, 0, 559.2), MM(0, 548.8, 559.2), MM(556, 548.8, 559.2)}},
    {"right_wall", GREEN, {MM(0, 0, 559.2), MM(0, 0, 0), MM(0, 548.8, 0), MM(0, 548.8, 559.2)}},
    {"left_wall", RED, {MM(552.8, 0, 0), MM(549.6, 0, 559.2), MM(556, 548.8, 559.2), MM(556, 548.8, 0)}},
    {"light", LIGHT, {MM(343, 548.8, 227), MM(343, 548.8, 332), MM(213, 548.8, 332), MM(213, 548.8, 227)}},
    {"short_block_top", WHITE, {MM(130, 165, 65), MM(82, 165, 225), MM(240, 165, 272), MM(290, 165, 114)}},
    {"short_block_side1", WHITE, {MM(290, 0, 114), MM(290, 165, 114), MM(240, 165, 272), MM(240, 0, 272)}},
    {"short_block_side2", WHITE, {MM(130, 0, 65), MM(130, 165, 65), MM(290, 165, 114), MM(290, 0, 114)}},
    {"short_block_side3", WHITE, {MM(82, 0, 225), MM(82, 165, 225), MM(130, 165, 65), MM(130, 0, 65)}},
    {"short_block_side4", WHITE, {MM(240, 0, 272), MM(240, 165, 272), MM(82, 165, 225), MM(82, 0, 225)}},
    {"tall_block_top", WHITE, {MM(423, 330, 247), MM(265, 330, 296), MM(314, 330, 456), MM(472, 330, 406)}},
    {"tall_block_side1", WHITE, {MM(423, 0, 247), MM(423, 330, 247), MM(472, 330, 406), MM(472, 0, 406)}},
    {"tall_block_side2", WHITE, {MM(472, 0, 406), MM(472, 330, 406), MM(314, 330, 456), MM(314, 0, 456)}},
    {"tall_block_side3", WHITE, {MM(314, 0, 456), MM(314, 330, 456), MM(265, 330, 296), MM(265, 0, 296)}},
    {"tall_block_side4", WHITE, {MM(265, 0, 296), MM(265, 330, 296), MM(423, 330, 247), MM(423, 0, 247)}},
};
#define NQUADS ((int)(sizeof QUADS / sizeof QUADS[0]))
#define PADDING 1 /* empty texels around each chart */

/* ---- small vector helpers ---- */

static void sub3(const double *a, const double *b, double *o) { for (int i = 0; i < 3; i++) o[i] = a[i] - b[i]; }
static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static void cross3(const double *a, const double *b, double *o)
{
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}
static void normalize3(double *a)
{
    double l = sqrt(dot3(a, a));
    for (int i = 0; i < 3; i++) a[i] /= l;
}

/* Area of a 2-D polygon (absolute). */
static double polygon_area(const double (*p)[2], int n)
{
    double a = 0;
    for (int i = 0; i < n; i++) {
        int j = (i + 1) % n;
        a += p[i][0] * p[j][1] - p[j][0] * p[i][1];
    }
    return fabs(a) / 2;
}

/* Area of the unit square at (x, y) inside the convex counter-clockwise polygon `poly`
 * (Sutherland-Hodgman: the square clipped by each edge's half-plane). */
static double texel_coverage(int x, int y, const double (*poly)[2], int npoly)
{
    double a[16][2] = {{x, y}, {x + 1, y}, {x + 1, y + 1}, {x, y + 1}}, b[16][2];
    int n = 4;
    for (int e = 0; e < npoly && n > 0; e++) {
        const double *p = poly[e], *q = poly[(e + 1) % npoly];
        int m = 0;
        for (int i = 0; i < n; i++) {
            const double *s = a[i], *t = a[(i + 1) % n];
            double ds = (q[0] - p[0]) * (s[1] - p[1]) - (q[1] - p[1]) * (s[0] - p[0]);
            double dt = (q[0] - p[0]) * (t[1] - p[1]) - (q[1] - p[1]) * (t[0] - p[0]);
            if (ds >= 0) { b[m][0] = s[0]; b[m][1] = s[1]; m++; }
            if ((ds >= 0) != (dt >= 0)) {
                double k = ds / (ds - dt);
                b[m][0] = s[0] + k * (t[0] - s[0]);
                b[m][1] = s[1] + k * (t[1] - s[1]);
                m++;
            }
        }
        memcpy(a, b, sizeof(double[2]) * m);
        n = m;
    }
    return n >= 3 ? polygon_area((const double(*)[2])a, n) : 0;
}

/* ---- the atlas ---- */

typedef struct {
    double area;      /* m^2 */
    double poly[4][2]; /* the quad in atlas texel coordinates */
    int x0, y0, w, h; /* its chart (padding included) in the atlas */
} Chart;

/* Lays each quad flat in its own plane at `density` texels per metre, then packs the charts in
 * shelves (tallest first) into an atlas `*aw` texels wide; returns the atlas height. */
static int build_atlas(double density, Chart *charts, int *aw)
{
    double total = 0;
    for (int q = 0; q < NQUADS; q++) {
        const Quad *Q = &QUADS[q];
        double e1[3], e3[3], n[3], u[3], w[3], d[3];
        sub3(Q->v[1], Q->v[0], e1);
        sub3(Q->v[3], Q->v[0], e3);
        cross3(e1, e3, n);
        normalize3(n);
        memcpy(u, e1, sizeof u);
        normalize3(u);
        cross3(n, u, w); /* (u, w, n) right-handed: the quad stays counter-clockwise in (u, w) */
        double lo[2] = {1e30, 1e30};
        for (int i = 0; i < 4; i++) {
            sub3(Q->v[i], Q->v[0], d);
            charts[q].poly[i][0] = dot3(d, u) * density;
            charts[q].poly[i][1] = dot3(d, w) * density;
            for (int k = 0; k < 2; k++) lo[k] = fmin(lo[k], charts[q].poly[i][k]);
        }
        double hi[2] = {-1e30, -1e30};
        for (int i = 0; i < 4; i++)
            for (int k = 0; k < 2; k++) {
                charts[q].poly[i][k] += PADDING - lo[k];
                hi[k] = fmax(hi[k], charts[q].poly[i][k]);
            }
        charts[q].w = (int)ceil(hi[0]) + PADDING;
        charts[q].h = (int)ceil(hi[1]) + PADDING;
        charts[q].area = polygon_area((const double(*)[2])charts[q].poly, 4) / (density * density);
        total += (double)charts[q].w * charts[q].h;
    }
    /* Shelf packing, tallest first, into a width of about 1.15 sqrt(total) (a multiple of 8). */
    int order[NQUADS];
    for (int i = 0; i < NQUADS; i++) order[i] = i;
    for (int i = 1; i < NQUADS; i++)
        for (int j = i; j > 0 && charts[order[j]].h > charts[order[j - 1]].h; j--) {
            int t = order[j]; order[j] = order[j - 1]; order[j - 1] = t;
        }
    int width = ((int)ceil(1.15 * sqrt(total)) + 7) / 8 * 8;
    for (int i = 0; i < NQUADS; i++)
        if (charts[i].w > width) width = (charts[i].w + 7) / 8 * 8;
    int x = 0, y = 0, shelf = 0;
    for (int i = 0; i < NQUADS; i++) {
        Chart *c = &charts[order[i]];
        if (x + c->w > width) { x = 0; y += shelf; shelf = 0; }
        c->x0 = x;
        c->y0 = y;
        x += c->w;
        if (c->h > shelf) shelf = c->h;
        for (int k = 0; k < 4; k++) { c->poly[k][0] += c->x0; c->poly[k][1] += c->y0; }
    }
    *aw = width;
    return y + shelf;
}

/* ---- a headless GL 3.3 core context on EGL ---- */

static EGLDisplay egl_dpy = EGL_NO_DISPLAY;

static int make_context(const char **how)
{
    static const EGLint ctx_attr[] = {
        EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
        EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_platform_display =
        (PFNEGLGETPLATFORMDISPLAYEXTPROC)eglGetProcAddress("eglGetPlatformDisplayEXT");
    for (int attempt = 0; attempt < 3; attempt++) {
        EGLSurface surf = EGL_NO_SURFACE;
        if (attempt == 0) {
            *how = "EGL surfaceless (EGL_PLATFORM_SURFACELESS_MESA)";
            if (!get_platform_display) continue;
            egl_dpy = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL);
        } else if (attempt == 1) {
            *how = "EGL device platform (EGL_PLATFORM_DEVICE_EXT), no surface";
            PFNEGLQUERYDEVICESEXTPROC query_devices =
                (PFNEGLQUERYDEVICESEXTPROC)eglGetProcAddress("eglQueryDevicesEXT");
            EGLDeviceEXT dev[8];
            EGLint ndev = 0;
            if (!get_platform_display || !query_devices || !query_devices(8, dev, &ndev) || ndev < 1) continue;
            egl_dpy = get_platform_display(EGL_PLATFORM_DEVICE_EXT, dev[0], NULL);
        } else {
            *how = "EGL default display, 1x1 pbuffer";
            egl_dpy = eglGetDisplay(EGL_DEFAULT_DISPLAY);
        }
        EGLint major, minor;
        if (egl_dpy == EGL_NO_DISPLAY || !eglInitialize(egl_dpy, &major, &minor)) continue;
        if (!eglBindAPI(EGL_OPENGL_API)) continue;
        const EGLint cfg_attr[] = {
            EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
            EGL_SURFACE_TYPE, attempt == 2 ? EGL_PBUFFER_BIT : 0,
            EGL_RED_SIZE, 8, EGL_GREEN_SIZE, 8, EGL_BLUE_SIZE, 8, EGL_NONE};
        EGLConfig cfg;
        EGLint ncfg = 0;
        if (!eglChooseConfig(egl_dpy, cfg_attr, &cfg, 1, &ncfg) || ncfg < 1) {
            eglTerminate(egl_dpy);
            continue;
        }
        EGLContext ctx = eglCreateContext(egl_dpy, cfg, EGL_NO_CONTEXT, ctx_attr);
        if (ctx == EGL_NO_CONTEXT) { eglTerminate(egl_dpy); continue; }
        if (attempt == 2) {
            const EGLint pb[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
            surf = eglCreatePbufferSurface(egl_dpy, cfg, pb);
            if (surf == EGL_NO_SURFACE) { eglTerminate(egl_dpy); continue; }
        }
        if (!eglMakeCurrent(egl_dpy, surf, surf, ctx)) { eglTerminate(egl_dpy); continue; }
        return 1;
    }
    return 0;
}

/* ---- drawing the scene onto lightmapper's hemicubes ---- */

typedef struct {
    float p[3];   /* position, m */
    float uv[2];  /* light-map coordinates in [0, 1] */
    float e[3];   /* emitted radiance */
    float rho[3]; /* reflectance */
} Vertex;

static GLuint compile(GLenum type, const char *src)
{
    GLuint s = glCreateShader(type);
    glShaderSource(s, 1, &src, NULL);
    glCompileShader(s);
    GLint ok;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[2048];
        glGetShaderInfoLog(s, sizeof log, NULL, log);
        fprintf(stderr, "shader: %s\n", log);
        exit(1);
    }
    return s;
}

/* Each surface shows E + rho * H, H read from the previous gather's light map (nearest texel:
 * the texels are constant elements). Back faces are black (one-sided surfaces, as in Radiant
 * and Mitsuba) with alpha 1; lightmapper's example instead writes alpha 0 there, which makes
 * lightmapper drop or renormalise texels that see back faces. */
static const char *VS =
    "#version 330 core\n"
    "layout(location = 0) in vec3 p;\n"
    "layout(location = 1) in vec2 uv;\n"
    "layout(location = 2) in vec3 e;\n"
    "layout(location = 3) in vec3 rho;\n"
    "uniform mat4 view, proj;\n"
    "out vec2 v_uv; out vec3 v_e; out vec3 v_rho;\n"
    "void main() { v_uv = uv; v_e = e; v_rho = rho; gl_Position = proj * view * vec4(p, 1.0); }\n";
static const char *FS =
    "#version 330 core\n"
    "uniform sampler2D H;\n"
    "in vec2 v_uv; in vec3 v_e; in vec3 v_rho;\n"
    "out vec4 colour;\n"
    "void main() {\n"
    "  vec3 b = v_e + v_rho * texture(H, v_uv).rgb;\n"
    "  colour = gl_FrontFacing ? vec4(b, 1.0) : vec4(0.0, 0.0, 0.0, 1.0);\n"
    "}\n";

/* lightmapper's weight: w(cos) = k cos, k normalising to the cosine-weighted mean (see top). */
static float cosine_weight(float cos_theta, void *k) { return *(float *)k * cos_theta; }

/* k = sum dw / sum dw cos over lightmapper's hemicube pixels (its lmSetHemisphereWeights loop). */
static float cosine_weight_scale(int size)
{
    double sw = 0, swc = 0, centre = (size - 1) * 0.5;
    for (int y = 0; y < size; y++)
        for (int x = 0; x < size; x++) {
            double dx = 2.0 * (x - centre) / size, dy = 2.0 * (y - centre) / size;
            double r = sqrt(dx * dx + dy * dy + 1), vz = 1 / r;
            double sa = vz * vz * vz;
            /* centre face, left/right halves, down/up halves */
            sw += 3 * sa;
            swc += sa * (vz + fabs(dx) / r + fabs(dy) / r);
        }
    return (float)(sw / swc);
}

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static void usage(void)
{
    fprintf(stderr,
            "usage: lightmapper_cornell [--density TEXELS_PER_M | --texels N] [--bounces N]\n"
            "  [--hemisphere 16..512] [--interpolation-passes 0..8] [--interpolation-threshold T]\n"
            "  [--no-interpolation] [--znear M] [--zfar M] [--distance-modifier X]\n");
    exit(2);
}

int main(int argc, char **argv)
{
    double density = 0, texels = 5080; /* by default: about 5,080 texels' worth of area */
    int bounces = 12, hemi = 64, passes = 4;
    float threshold = 0.01f, znear = 0.001f, zfar = 10.0f, distmod = 0.0f;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--no-interpolation")) { passes = 0; continue; }
        if (!v) usage();
        if (!strcmp(a, "--density")) density = atof(v);
        else if (!strcmp(a, "--texels")) texels = atof(v);
        else if (!strcmp(a, "--bounces")) bounces = atoi(v);
        else if (!strcmp(a, "--hemisphere")) hemi = atoi(v);
        else if (!strcmp(a, "--interpolation-passes")) passes = atoi(v);
        else if (!strcmp(a, "--interpolation-threshold")) threshold = (float)atof(v);
        else if (!strcmp(a, "--znear")) znear = (float)atof(v);
        else if (!strcmp(a, "--zfar")) zfar = (float)atof(v);
        else if (!strcmp(a, "--distance-modifier")) distmod = (float)atof(v);
        else usage();
        i++;
    }
    if ((hemi & (hemi - 1)) || hemi < 16 || hemi > 512 || passes < 0 || passes > 8 || bounces < 1) usage();

    /* Geometry and atlas. */
    double total_area = 0;
    for (int q = 0; q < NQUADS; q++) {
        double e1[3], e2[3], e3[3], c[3];
        sub3(QUADS[q].v[1], QUADS[q].v[0], e1);
        sub3(QUADS[q].v[2], QUADS[q].v[0], e2);
        sub3(QUADS[q].v[3], QUADS[q].v[0], e3);
        cross3(e1, e2, c);
        total_area += sqrt(dot3(c, c)) / 2;
        cross3(e2, e3, c);
        total_area += sqrt(dot3(c, c)) / 2;
    }
    if (density <= 0) density = sqrt(texels / total_area);
    Chart charts[NQUADS];
    int W, H = build_atlas(density, charts, &W);
    {
        /* lightmapper keeps the hemicubes of one pass in a W x H texture, in blocks of
         * bx x by (its batch: 1536 / (3 size) x 512 / size), and asserts that the row after
         * the last block still fits: room for every chart texel, and a spare row. */
        int bx = 1536 / (3 * hemi), by = 512 / hemi, per_row = W / bx;
        long chart_texels = 0;
        for (int q = 0; q < NQUADS; q++) chart_texels += (long)charts[q].w * charts[q].h;
        long blocks = (chart_texels + (long)bx * by - 1) / ((long)bx * by);
        int rows = (int)((blocks + per_row - 1) / per_row) + 1;
        if (H < rows * by + 1) H = rows * by + 1;
    }

    /* Texels: the charts' area in texels, and the texels that overlap a quad (lightmapper's
     * conservative rasteriser gathers at each of those, at the centroid of the covered part). */
    double *cover = calloc((size_t)W * H, sizeof *cover);
    int *owner = malloc(sizeof(int) * W * H);
    int covered = 0;
    for (int i = 0; i < W * H; i++) owner[i] = -1;
    for (int q = 0; q < NQUADS; q++)
        for (int y = charts[q].y0; y < charts[q].y0 + charts[q].h; y++)
            for (int x = charts[q].x0; x < charts[q].x0 + charts[q].w; x++) {
                double c = texel_coverage(x, y, (const double(*)[2])charts[q].poly, 4);
                if (c > 0) { cover[y * W + x] = c; owner[y * W + x] = q; covered++; }
            }

    Vertex verts[NQUADS * 6];
    static const int TRI[6] = {0, 1, 2, 0, 2, 3}; /* as in the glTF */
    for (int q = 0; q < NQUADS; q++)
        for (int k = 0; k < 6; k++) {
            Vertex *v = &verts[q * 6 + k];
            const Material *m = &MATERIALS[QUADS[q].material];
            for (int c = 0; c < 3; c++) {
                v->p[c] = (float)QUADS[q].v[TRI[k]][c];
                v->e[c] = (float)m->emission[c];
                v->rho[c] = (float)m->rho[c];
            }
            v->uv[0] = (float)(charts[q].poly[TRI[k]][0] / W);
            v->uv[1] = (float)(charts[q].poly[TRI[k]][1] / H);
        }

    fprintf(stderr, "lightmapper_cornell: %d quads, %.4f m^2, %.2f texels/m, atlas %d x %d, "
                    "%.0f texels of chart area, %d texels overlapping a quad\n",
            NQUADS, total_area, density, W, H, total_area * density * density, covered);
    fprintf(stderr, "  hemisphere %d, zNear %g, zFar %g, interpolation passes %d, threshold %g, "
                    "distance modifier %g, %d bounces\n",
            hemi, znear, zfar, passes, threshold, distmod, bounces);

    /* Context. */
    double t0 = now();
    const char *how = "";
    if (!make_context(&how)) {
        fprintf(stderr, "no headless GL 3.3 core context (EGL error 0x%x)\n", eglGetError());
        return 1;
    }
    double t1 = now();
    fprintf(stderr, "  context: %s; GL %s; %s\n", how, glGetString(GL_VERSION), glGetString(GL_RENDERER));

    /* Bake. */
    GLuint prog = glCreateProgram();
    glAttachShader(prog, compile(GL_VERTEX_SHADER, VS));
    glAttachShader(prog, compile(GL_FRAGMENT_SHADER, FS));
    glLinkProgram(prog);
    GLint u_view = glGetUniformLocation(prog, "view"), u_proj = glGetUniformLocation(prog, "proj");
    GLint u_h = glGetUniformLocation(prog, "H");
    GLuint vao, vbo, tex;
    glGenVertexArrays(1, &vao);
    glBindVertexArray(vao);
    glGenBuffers(1, &vbo);
    glBindBuffer(GL_ARRAY_BUFFER, vbo);
    glBufferData(GL_ARRAY_BUFFER, sizeof verts, verts, GL_STATIC_DRAW);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), (void *)offsetof(Vertex, p));
    glVertexAttribPointer(1, 2, GL_FLOAT, GL_FALSE, sizeof(Vertex), (void *)offsetof(Vertex, uv));
    glVertexAttribPointer(2, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), (void *)offsetof(Vertex, e));
    glVertexAttribPointer(3, 3, GL_FLOAT, GL_FALSE, sizeof(Vertex), (void *)offsetof(Vertex, rho));
    for (int i = 0; i < 4; i++) glEnableVertexAttribArray(i);
    glBindVertexArray(0);

    float *lm = calloc((size_t)W * H * 3, sizeof(float));
    float *shown = calloc((size_t)W * H * 3, sizeof(float));
    glGenTextures(1, &tex);
    glBindTexture(GL_TEXTURE_2D, tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGB32F, W, H, 0, GL_RGB, GL_FLOAT, shown); /* H_0 = 0 */

    lm_context *ctx = lmCreate(hemi, znear, zfar, 0.0f, 0.0f, 0.0f, passes, threshold, distmod);
    if (!ctx) { fprintf(stderr, "lmCreate failed\n"); return 1; }
    float k = cosine_weight_scale(hemi);
    lmSetHemisphereWeights(ctx, cosine_weight, &k);
    srand(1); /* lightmapper jitters each hemicube's rotation with rand() */

    long hemicubes_total = 0;
    for (int b = 0; b < bounces; b++) {
        double tb = now();
        memset(lm, 0, sizeof(float) * W * H * 3); /* lightmapper only fills zero texels */
        lmSetTargetLightmap(ctx, lm, W, H, 3);
        lmSetGeometry(ctx, NULL, LM_FLOAT, verts[0].p, sizeof(Vertex), LM_NONE, NULL, 0,
                      LM_FLOAT, verts[0].uv, sizeof(Vertex), NQUADS * 6, LM_NONE, NULL);
        int vp[4];
        float view[16], proj[16];
        long sides = 0;
        while (lmBegin(ctx, vp, view, proj)) {
            /* lightmapper has bound its hemicube framebuffer; its own passes change the
             * program, the VAO and the textures, so bind ours every time. */
            glViewport(vp[0], vp[1], vp[2], vp[3]);
            glEnable(GL_DEPTH_TEST);
            glDisable(GL_CULL_FACE);
            glUseProgram(prog);
            glUniformMatrix4fv(u_view, 1, GL_FALSE, view);
            glUniformMatrix4fv(u_proj, 1, GL_FALSE, proj);
            glActiveTexture(GL_TEXTURE0);
            glBindTexture(GL_TEXTURE_2D, tex);
            glUniform1i(u_h, 0);
            glBindVertexArray(vao);
            glDrawArrays(GL_TRIANGLES, 0, NQUADS * 6);
            glBindVertexArray(0);
            lmEnd(ctx);
            sides++;
        }
        hemicubes_total += sides / 5;
        /* Convergence: the relative L1 change of H over the covered texels. */
        double change = 0, size = 0;
        for (int i = 0; i < W * H; i++)
            if (owner[i] >= 0)
                for (int c = 0; c < 3; c++) {
                    change += fabs(lm[3 * i + c] - shown[3 * i + c]);
                    size += fabs(lm[3 * i + c]);
                }
        /* The light map to show next: this gather's H, one texel of dilation as a guard
         * against sampling the padding at a chart's edge. */
        lmImageDilate(lm, shown, W, H, 3);
        glBindTexture(GL_TEXTURE_2D, tex);
        glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, W, H, GL_RGB, GL_FLOAT, shown);
        fprintf(stderr, "  bounce %2d: %ld hemicubes rendered, %.2f s, H changed by %.2e (relative L1)\n",
                b + 1, sides / 5, now() - tb, change / fmax(size, 1e-300));
    }
    glFinish();
    double t2 = now();

    /* Per-surface means: texels weighted by the area of the quad inside them. */
    double mean[NQUADS][3] = {{0}}, weight[NQUADS] = {0};
    int unset = 0;
    for (int i = 0; i < W * H; i++) {
        int q = owner[i];
        if (q < 0) continue;
        const float *h = lm + 3 * i;
        if (h[0] == 0 && h[1] == 0 && h[2] == 0) { unset++; continue; } /* lightmapper left it */
        const Material *m = &MATERIALS[QUADS[q].material];
        for (int c = 0; c < 3; c++) mean[q][c] += cover[i] * (m->emission[c] + m->rho[c] * h[c]);
        weight[q] += cover[i];
    }
    printf("name,r,g,b,area_m2,emitter\n");
    for (int q = 0; q < NQUADS; q++) {
        const Material *m = &MATERIALS[QUADS[q].material];
        int emitter = m->emission[0] > 0 || m->emission[1] > 0 || m->emission[2] > 0;
        printf("%s,%.6g,%.6g,%.6g,%.6g,%d\n", QUADS[q].name, mean[q][0] / weight[q],
               mean[q][1] / weight[q], mean[q][2] / weight[q], charts[q].area, emitter);
    }
    fprintf(stderr, "  %ld hemicubes in all (%.0f per bounce); %d covered texels left unset by lightmapper\n",
            hemicubes_total, (double)hemicubes_total / bounces, unset);
    fprintf(stderr, "  weight k = %.6f (w(cos) = k cos)\n", k);
    fprintf(stderr, "wall: context %.3f s, bake %.3f s, bake + context %.3f s\n", t1 - t0, t2 - t1, t2 - t0);

    lmDestroy(ctx);
    free(lm);
    free(shown);
    free(cover);
    free(owner);
    eglTerminate(egl_dpy);
    return 0;
}
