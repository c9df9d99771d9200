/*
 * nisflow/version.h - the library's version, at compile time and at run time.
 *
 * The three macros are the single source of the version number: CMake reads them from this
 * file. Compare NF_VERSION_MAJOR against nf_version_string() to detect a header/library
 * mismatch. The ABI is stable within one major version once the major version is >= 1;
 * before 1.0 each minor version is an ABI of its own (SONAME libnisflow.so.0.MINOR, and the
 * CMake package accepts only the same minor version: docs/integration.md).
 *
 * It also defines NF_API (the symbols the shared library exports), NF_DEPRECATED (names kept
 * for one minor version after a rename) and NF_EXTERN_C_BEGIN/END (C linkage under C++), which
 * every other public header uses through this one.
 */
#ifndef NISFLOW_VERSION_H
#define NISFLOW_VERSION_H

#if defined(_WIN32) && !defined(NISFLOW_STATIC)
#if defined(NISFLOW_BUILDING)
#define NF_API __declspec(dllexport)
#else
#define NF_API __declspec(dllimport)
#endif
#elif defined(__GNUC__) || defined(__clang__)
#define NF_API __attribute__((visibility("default")))
#else
#define NF_API
#endif

/* Marks a name kept for one minor version after it was renamed (CHANGELOG.md lists them). The
 * library's own sources, which define the old names, see no warning. */
#if defined(NISFLOW_BUILDING)
#define NF_DEPRECATED(replacement)
#elif defined(__GNUC__) || defined(__clang__)
#define NF_DEPRECATED(replacement) __attribute__((deprecated("use " replacement)))
#elif defined(_MSC_VER)
#define NF_DEPRECATED(replacement) __declspec(deprecated("use " replacement))
#else
#define NF_DEPRECATED(replacement)
#endif

#ifdef __cplusplus
#define NF_EXTERN_C_BEGIN extern "C" {
#define NF_EXTERN_C_END }
#else
#define NF_EXTERN_C_BEGIN
#define NF_EXTERN_C_END
#endif

#define NF_VERSION_MAJOR 0
#define NF_VERSION_MINOR 10
#define NF_VERSION_PATCH 0

NF_EXTERN_C_BEGIN

/* The version of the linked library as "MAJOR.MINOR.PATCH". The string is static: never free
 * it. Thread-safe. */
NF_API const char *nf_version_string(void);

NF_EXTERN_C_END

#endif /* NISFLOW_VERSION_H */
