/*
 * nisflow/nisflow.h - the umbrella header of libnisflow, neural importance sampling of
 * directions for path guiding. Include this one header to get the whole C API.
 *
 *   version.h  version macros and nf_version_string
 *   status.h   nf_status codes and error messages
 *   model.h    configuration, model life cycle, nf_sample / nf_pdf
 *   vertex.h   one render thread's answers at path vertices: a point, or a cell's table
 *   train.h    training steps, parameter access
 *   path.h     training samples from a traced path (the backward radiance walk)
 *   policy.h   the path policy and nf_path_state, one camera path's guiding state
 *   guide.h    the guide: sample store, training, published models
 *   schedule.h the schedule: train, guided or plain passes in a time budget, the image
 *   io.h       save / load / serialize
 */
#ifndef NISFLOW_NISFLOW_H
#define NISFLOW_NISFLOW_H

#include "version.h"
#include "status.h"
#include "model.h"
#include "vertex.h"
#include "train.h"
#include "path.h"
#include "policy.h"
#include "guide.h"
#include "schedule.h"
#include "io.h"

#endif /* NISFLOW_NISFLOW_H */
