/* soname_probe.c - a one-function shared library built with libnisflow's VERSION and SOVERSION
 * in static builds, so that test_version_policy checks the SONAME the policy gives. */
int nf_soname_probe(void);
int nf_soname_probe(void) { return 0; }
