/*
 * nisflow/io.h - saving and loading models.
 *
 * The format is versioned, little-endian on every host, and carries the configuration (less
 * the allocator and callbacks), the parameters, the AdamW state (so training resumes exactly)
 * and a CRC-32 checksum. Loading validates everything and refuses any inconsistency in the
 * data with NF_ERROR_FORMAT; it never crashes on hostile input. docs/format.md describes the
 * layout.
 */
#ifndef NISFLOW_IO_H
#define NISFLOW_IO_H

#include <stddef.h>

#include "version.h"
#include "model.h"
#include "status.h"

NF_EXTERN_C_BEGIN

/* Writes the model to a file (created or truncated). NF_ERROR_IO if the file cannot be
 * written completely (the message names the path and gives strerror's reason). Allocates one
 * temporary buffer of the file's size through the model's allocator. Thread-safe on a const model.
 */
NF_API nf_status nf_model_save(const nf_model *m, const char *path);

/* Reads a model written by nf_model_save. `custom` supplies the callbacks of a model saved
 * with NF_PRIOR_CUSTOM (required then, ignored otherwise); it is copied. A custom-prior model
 * without callbacks is refused with NF_ERROR_INVALID_ARGUMENT (the file is fine, the call is
 * not). NF_ERROR_IO when the file cannot be opened or read (the message gives the C
 * library's reason, strerror). Every message begins with "nf_model_load: '<path>':" (a path
 * over 120 bytes keeps its last 117). The model uses the default allocator and NF_ISA_AUTO;
 * nf_model_set_isa chooses another instruction set, for results identical across machines.
 * *out is NULL on failure. Thread-safe. */
NF_API nf_status nf_model_load(const char *path, const nf_prior_callbacks *custom, nf_model **out);

/* Serializes into a caller-owned buffer. With buf NULL only *size is set (the bytes needed).
 * With a buffer smaller than needed, returns NF_ERROR_CAPACITY, writes nothing into it and
 * sets *size to the bytes needed. NULL m or size: NF_ERROR_INVALID_ARGUMENT. Thread-safe on a
 * const model; never allocates. */
NF_API nf_status nf_model_serialize(const nf_model *m, void *buf, size_t capacity, size_t *size);

/* Creates a model from exactly `size` bytes written by nf_model_serialize. `custom` as for
 * nf_model_load. The buffer is only read and may be freed afterwards. Thread-safe. */
NF_API nf_status nf_model_deserialize(const void *buf, size_t size,
                                      const nf_prior_callbacks *custom, nf_model **out);

NF_EXTERN_C_END

#endif /* NISFLOW_IO_H */
