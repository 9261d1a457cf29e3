/* main's photometric texel model at cfe4354, the peer of bench-pn-model and
 * test-photometric-model (pn-model-peer.c). */
#pragma once
#include "photometric.h"

int pn_model_peer_texel(const struct imp_btf_sample *s, int n, const struct imp_photometric_params *p,
                        struct imp_pn_texel *ret);
