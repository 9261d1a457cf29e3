/* Placeholder translation unit until the scene model lands. */
int imp_sim_placeholder_;
