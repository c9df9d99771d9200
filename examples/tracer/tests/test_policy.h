/*
 * test_policy.h - the guiding policy the tracer's tests render with: probability g, and none
 * of the policy's other levers (no boost cap, light MIS by the mixture at every depth, every
 * rough conductor guided), so that a test sees the plain one-sample mixture unless it turns
 * a lever on itself.
 */
#ifndef TRACER_TEST_POLICY_H
#define TRACER_TEST_POLICY_H

#include <nisflow/nisflow.h>

static inline nf_guide_policy test_policy(float g)
{
    nf_guide_policy p;
    nf_guide_policy_init(&p);
    p.mixture_prob = g;
    p.max_boost = 0.0f;
    p.light_mis_depth = 0;
    p.min_roughness = 0.0f;
    return p;
}

#endif /* TRACER_TEST_POLICY_H */
