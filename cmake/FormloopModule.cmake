# formloop_module(NAME [SOURCES ...] [DEPS ...])
# Declares the library target formloop_<NAME> (alias formloop::<NAME>) for one folder.
# Includes name the folder ("core/status.h"), so the repository root is the include root.
# A folder whose capability has not landed yet has no SOURCES and is an INTERFACE target that only
# carries its downward links, so the layer table stays true from the start.
function(formloop_module name)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPS" ${ARGN})
  if(ARG_SOURCES)
    add_library(formloop_${name} STATIC ${ARG_SOURCES})
    target_include_directories(formloop_${name} PUBLIC ${PROJECT_SOURCE_DIR})
    target_link_libraries(formloop_${name} PUBLIC ${ARG_DEPS} PRIVATE formloop_warnings)
    set_target_properties(formloop_${name} PROPERTIES POSITION_INDEPENDENT_CODE ON)
  else()
    add_library(formloop_${name} INTERFACE)
    target_include_directories(formloop_${name} INTERFACE ${PROJECT_SOURCE_DIR})
    target_link_libraries(formloop_${name} INTERFACE ${ARG_DEPS})
  endif()
  add_library(formloop::${name} ALIAS formloop_${name})
endfunction()
