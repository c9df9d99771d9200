# nf_install_pkgconfig(<template> <file name> <library type>)
#
# Installs a pkg-config file into ${CMAKE_INSTALL_LIBDIR}/pkgconfig. The prefix is written at
# install time, so `cmake --install build --prefix /somewhere` yields a correct file even when
# it differs from the CMAKE_INSTALL_PREFIX the build was configured with.

include_guard(GLOBAL)

function(nf_install_pkgconfig template name library_type)
    # Directories relative to the prefix become ${prefix}/..., absolute ones stay as they are.
    foreach(_dir LIBDIR INCLUDEDIR)
        if(IS_ABSOLUTE "${CMAKE_INSTALL_${_dir}}")
            set(NF_PC_${_dir} "${CMAKE_INSTALL_${_dir}}")
        else()
            set(NF_PC_${_dir} "\${prefix}/${CMAKE_INSTALL_${_dir}}")
        endif()
    endforeach()
    # A static libnisflow needs libm at the consumer's link; `pkg-config --libs` (without
    # --static, as most build systems call it) must say so too.
    if(library_type STREQUAL "STATIC_LIBRARY")
        set(NF_PC_CFLAGS " -DNISFLOW_STATIC")
        set(NF_PC_LIBS_STATIC " -lm")
    else()
        set(NF_PC_CFLAGS "")
        set(NF_PC_LIBS_STATIC "")
    endif()
    # First pass: everything but the prefix, which survives as @NF_PC_PREFIX@.
    set(NF_PC_PREFIX "@NF_PC_PREFIX@")
    set(_stage "${CMAKE_CURRENT_BINARY_DIR}/${name}.stage")
    set(_final "${CMAKE_CURRENT_BINARY_DIR}/${name}")
    configure_file("${template}" "${_stage}" @ONLY)
    # Second pass, at install time: the prefix actually installed to.
    install(CODE "set(NF_PC_PREFIX \"\${CMAKE_INSTALL_PREFIX}\")
configure_file(\"${_stage}\" \"${_final}\" @ONLY)")
    install(FILES "${_final}" DESTINATION "${CMAKE_INSTALL_LIBDIR}/pkgconfig")
endfunction()
