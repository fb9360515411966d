# Warnings are errors everywhere we own the code. The image kernels and the geometry add
# the conversion family (libcanard's set), where a silent narrowing is a wrong pixel or mm.
set(ALACS_WARNINGS -Wall -Wextra -Wpedantic -Werror -Wshadow -Wnon-virtual-dtor
    -Wold-style-cast -Wcast-align -Wunused -Woverloaded-virtual
    -Wimplicit-fallthrough)
set(ALACS_STRICT_WARNINGS -Wconversion -Wsign-conversion -Wdouble-promotion -Wswitch-enum)
# GCC 12 at -O2/-O3 reports -Wrestrict inside libstdc++ for `"literal" + std::string`
# (GCC bug 105329, fixed in 13): a false positive that -Werror would turn into a failed
# Release build. Only that one warning is relaxed, and only for GCC 12.
if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_GREATER_EQUAL 12
   AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
  list(APPEND ALACS_WARNINGS -Wno-restrict)
endif()
# Under ASan+UBSan at -O1 (ALACS_SANITIZE), GCC's -Wmaybe-uninitialized fires inside
# libstdc++ (std::regex in Catch2, std::optional of vectors): false positives of the
# instrumentation. Relaxed there only; the Release build keeps the warning.
if(ALACS_SANITIZE AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
  list(APPEND ALACS_WARNINGS -Wno-maybe-uninitialized)
endif()

# alacs_component(NAME SOURCES... [STRICT] [DEPS ...])
function(alacs_component name)
  cmake_parse_arguments(ARG "STRICT" "" "SOURCES;DEPS;PRIVATE_DEPS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  target_include_directories(${name} PUBLIC ${PROJECT_SOURCE_DIR}/edge)
  target_compile_options(${name} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:${ALACS_WARNINGS}> ${ALACS_SANITIZE_OPTIMIZE})
  if(ARG_STRICT)
    target_compile_options(${name} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:${ALACS_STRICT_WARNINGS}>)
  endif()
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()
