/* The float32 TIFF heightmap (export.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <tiffio.h>
#include "export.h"

int imp_export_tiff_height(const struct imp_copy *c, const char *path, struct imp_error *err) {
        TIFF *tif = TIFFOpen(path, "w");
        if (!tif)
                return imp_error_set(err, -EIO, "%s: cannot create the TIFF", path);
        char desc[512];
        snprintf(desc, sizeof desc,
                 "{\"format\": \"impasto-heightmap\", \"units\": \"mm\", \"pitch_mm\": %.17g, \"h_ref_mm\": %.9g, "
                 "\"nodata\": \"NaN\", \"rows\": \"texel row j\"}", c->pitch_mm, c->h_ref_mm);
        float res = (float) (10.0 / c->pitch_mm);   /* pixels per centimetre */
        bool ok = TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, (uint32_t) c->nx) &&
                  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, (uint32_t) c->ny) &&
                  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, (uint16_t) 1) &&
                  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, (uint16_t) 32) &&
                  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, (uint16_t) SAMPLEFORMAT_IEEEFP) &&
                  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, (uint16_t) PHOTOMETRIC_MINISBLACK) &&
                  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, (uint16_t) PLANARCONFIG_CONTIG) &&
                  TIFFSetField(tif, TIFFTAG_COMPRESSION, (uint16_t) COMPRESSION_ADOBE_DEFLATE) &&
                  TIFFSetField(tif, TIFFTAG_PREDICTOR, (uint16_t) PREDICTOR_FLOATINGPOINT) &&
                  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, (uint32_t) IMP_MAX(1, 65536 / (4 * c->nx))) &&
                  TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, (uint16_t) RESUNIT_CENTIMETER) &&
                  TIFFSetField(tif, TIFFTAG_XRESOLUTION, res) && TIFFSetField(tif, TIFFTAG_YRESOLUTION, res) &&
                  TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, desc) &&
                  TIFFSetField(tif, TIFFTAG_SOFTWARE, "impasto export");
        float *row = malloc(sizeof *row * (size_t) c->nx);
        for (int j = 0; ok && row && j < c->ny; j++) {
                for (int i = 0; i < c->nx; i++) {
                        size_t k = (size_t) j * c->nx + i;
                        row[i] = c->mask[k] ? c->height[k] : NAN;
                }
                ok = TIFFWriteScanline(tif, row, (uint32_t) j, 0) >= 0;
        }
        free(row);
        TIFFClose(tif);
        if (!row)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return ok ? 0 : imp_error_set(err, -EIO, "%s: writing the TIFF failed", path);
}
