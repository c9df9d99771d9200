# version_policy.cmake - the version and ABI policy of docs/integration.md ("Versions and
# ABI"), run by CTest as test_version_policy:
#
#   cmake -DVERSION=0.2.0 -DVERSION_FILE=<build>/nisflowConfigVersion.cmake
#         -DLIBRARY=<shared library whose SONAME to check> -DREADELF=<readelf>
#         [-DLIBNAME=<its name without lib, default nisflow>]
#         [-DINSTALL_FROM=<build dir> -DINSTALL_PREFIX=<scratch dir>] -P version_policy.cmake
#
# 1. The package version file that `cmake --install` ships answers find_package's questions
#    (the protocol of cmake-packages(7): PACKAGE_FIND_VERSION* in, PACKAGE_VERSION_COMPATIBLE
#    out): before 1.0 only the same minor version is compatible, from 1.0 the same major.
# 2. The SONAME is libnisflow.so.0.MINOR before 1.0 and libnisflow.so.MAJOR after. With
#    INSTALL_FROM (a shared build) the library is installed into INSTALL_PREFIX and the
#    installed file is read, and the file named by the SONAME must exist there (it is what the
#    dynamic loader opens); otherwise LIBRARY is a probe built with the same properties.
# 3. With -DDOCS=<file;file;...>, every find_package(nisflow X.Y...) those files show a user is
#    one that the version file accepts (the README's went stale at 0.5 against 0.7).
cmake_minimum_required(VERSION 3.20)

foreach(var VERSION VERSION_FILE LIBRARY)
    if(NOT DEFINED ${var})
        message(FATAL_ERROR "version_policy.cmake: -D${var}=... is required")
    endif()
endforeach()
string(REGEX MATCH "^([0-9]+)\\.([0-9]+)\\.([0-9]+)$" _ok "${VERSION}")
if(NOT _ok)
    message(FATAL_ERROR "version_policy.cmake: VERSION '${VERSION}' is not MAJOR.MINOR.PATCH")
endif()
set(major ${CMAKE_MATCH_1})
set(minor ${CMAKE_MATCH_2})
set(patch ${CMAKE_MATCH_3})
if(NOT DEFINED LIBNAME)
    set(LIBNAME nisflow)
endif()

# --- 1. find_package's version check ------------------------------------------------------

# Asks the version file whether a request for `request` (MAJOR.MINOR[.PATCH]) is satisfied.
function(nf_check_request request expect)
    string(REPLACE "." ";" parts "${request}")
    list(LENGTH parts count)
    list(APPEND parts 0 0 0)
    list(GET parts 0 PACKAGE_FIND_VERSION_MAJOR)
    list(GET parts 1 PACKAGE_FIND_VERSION_MINOR)
    list(GET parts 2 PACKAGE_FIND_VERSION_PATCH)
    set(PACKAGE_FIND_VERSION_TWEAK 0)
    set(PACKAGE_FIND_VERSION "${request}")
    set(PACKAGE_FIND_VERSION_COUNT ${count})
    set(PACKAGE_FIND_NAME nisflow)
    unset(PACKAGE_VERSION_COMPATIBLE)
    unset(PACKAGE_VERSION_UNSUITABLE)
    include("${VERSION_FILE}")
    if(PACKAGE_VERSION_UNSUITABLE)
        set(PACKAGE_VERSION_COMPATIBLE FALSE)
    endif()
    if(PACKAGE_VERSION_COMPATIBLE)
        set(got TRUE)
    else()
        set(got FALSE)
    endif()
    if(NOT got STREQUAL expect)
        message(SEND_ERROR "find_package(nisflow ${request}) against ${PACKAGE_VERSION}: "
                           "compatible = ${got}, the policy says ${expect}")
    else()
        message(STATUS "find_package(nisflow ${request}) against ${PACKAGE_VERSION}: ${got}")
    endif()
endfunction()

math(EXPR next_minor "${minor} + 1")
math(EXPR next_major "${major} + 1")
nf_check_request("${major}.${minor}" TRUE)
nf_check_request("${major}.${minor}.${patch}" TRUE)
nf_check_request("${major}.${next_minor}" FALSE)
nf_check_request("${next_major}.0" FALSE)
if(major EQUAL 0)
    if(minor GREATER 0)
        math(EXPR prev_minor "${minor} - 1")
        nf_check_request("0.${prev_minor}" FALSE) # an older minor: another ABI
    endif()
    set(soname "lib${LIBNAME}.so.0.${minor}")
else()
    if(minor GREATER 0)
        math(EXPR prev_minor "${minor} - 1")
        nf_check_request("${major}.${prev_minor}" TRUE) # same major: compatible
    endif()
    set(soname "lib${LIBNAME}.so.${major}")
endif()

# --- 2. The SONAME ------------------------------------------------------------------------

if(NOT READELF)
    message(STATUS "no readelf (not an ELF platform): SONAME not checked")
else()
    set(library "${LIBRARY}")
    if(DEFINED INSTALL_FROM)
        file(REMOVE_RECURSE "${INSTALL_PREFIX}")
        execute_process(COMMAND "${CMAKE_COMMAND}" --install "${INSTALL_FROM}" --prefix
                                "${INSTALL_PREFIX}"
                        RESULT_VARIABLE rc OUTPUT_QUIET)
        if(NOT rc EQUAL 0)
            message(FATAL_ERROR "cmake --install ${INSTALL_FROM} failed: ${rc}")
        endif()
        file(GLOB_RECURSE installed "${INSTALL_PREFIX}/libnisflow.so.${major}.${minor}.${patch}")
        if(NOT installed)
            message(FATAL_ERROR "no libnisflow.so.${major}.${minor}.${patch} under ${INSTALL_PREFIX}")
        endif()
        list(GET installed 0 library)
        get_filename_component(libdir "${library}" DIRECTORY)
        if(NOT EXISTS "${libdir}/${soname}")
            message(SEND_ERROR "the install has no ${libdir}/${soname} for the loader to open")
        endif()
    endif()
    execute_process(COMMAND "${READELF}" -d "${library}" OUTPUT_VARIABLE dynamic
                    RESULT_VARIABLE rc)
    if(NOT rc EQUAL 0 OR NOT dynamic MATCHES "\\(SONAME\\)[^\n]*\\[([^]\n]*)\\]")
        message(FATAL_ERROR "readelf -d ${library}: no SONAME")
    endif()
    if(NOT CMAKE_MATCH_1 STREQUAL soname)
        message(SEND_ERROR "${library}: SONAME ${CMAKE_MATCH_1}, the policy says ${soname}")
    else()
        message(STATUS "${library}: SONAME ${CMAKE_MATCH_1}")
    endif()
endif()

# --- 3. The find_package lines the docs show ---------------------------------------------

if(DEFINED DOCS)
    set(found 0)
    foreach(doc IN LISTS DOCS)
        file(STRINGS "${doc}" lines REGEX "find_package\\(nisflow [0-9]")
        foreach(line IN LISTS lines)
            string(REGEX MATCH "find_package\\(nisflow ([0-9]+\\.[0-9]+(\\.[0-9]+)?)" _m "${line}")
            nf_check_request("${CMAKE_MATCH_1}" TRUE)
            message(STATUS "${doc}: find_package(nisflow ${CMAKE_MATCH_1}) is accepted")
            math(EXPR found "${found} + 1")
        endforeach()
    endforeach()
    if(found EQUAL 0)
        message(SEND_ERROR "no find_package(nisflow X.Y) line in ${DOCS}")
    endif()
endif()
