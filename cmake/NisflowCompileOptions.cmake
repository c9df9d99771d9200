# Compiler flags shared by every target of the project.
#
#   nf_target_warnings(<target>)    -Wall -Wextra -Wpedantic on the target's C and C++
#                                   sources, plus -Werror when NF_WARNINGS_AS_ERRORS is ON.
#   nf_enable_sanitizers(<list>)    -fsanitize=<list> on compile and link of every target
#                                   defined afterwards in this directory and below.

include_guard(GLOBAL)

function(nf_target_warnings target)
    set(_flags -Wall -Wextra -Wpedantic)
    if(NF_WARNINGS_AS_ERRORS)
        list(APPEND _flags -Werror)
    endif()
    target_compile_options(${target} PRIVATE
        "$<$<COMPILE_LANG_AND_ID:C,GNU,Clang,AppleClang>:${_flags}>"
        "$<$<COMPILE_LANG_AND_ID:CXX,GNU,Clang,AppleClang>:${_flags}>")
endfunction()

macro(nf_enable_sanitizers sanitizers)
    if(NOT "${sanitizers}" STREQUAL "")
        if(NOT CMAKE_C_COMPILER_ID MATCHES "GNU|Clang")
            message(FATAL_ERROR "NF_SANITIZE needs GCC or Clang (found ${CMAKE_C_COMPILER_ID})")
        endif()
        add_compile_options(-fsanitize=${sanitizers} -fno-sanitize-recover=all
                            -fno-omit-frame-pointer)
        add_link_options(-fsanitize=${sanitizers} -fno-sanitize-recover=all)
        message(STATUS "nisflow: sanitizers enabled: ${sanitizers}")
    endif()
endmacro()
