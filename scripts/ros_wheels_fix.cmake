# Injected into every interface package by scripts/build_interfaces.sh through
# -DCMAKE_PROJECT_INCLUDE (so the packages' own CMakeLists.txt stay as in a normal ROS 2 tree).
#
# The ROS 2 Jazzy wheels on PyPI were built in a manylinux container and export imported targets
# whose INTERFACE_INCLUDE_DIRECTORIES contain /opt/python/cp311-cp311/include/python3.11, a path
# that does not exist here; CMake then stops generation with "includes non-existent path". At the
# end of the top-level directory (after rosidl_generate_interfaces() imported those targets) the
# deferred call below removes every include directory under /opt/python/ from them.
function(roadbev_drop_wheel_build_paths)
  get_property(_targets DIRECTORY "${CMAKE_SOURCE_DIR}" PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _targets)
    get_target_property(_dirs ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(NOT _dirs)
      continue()
    endif()
    set(_kept "")
    foreach(_dir IN LISTS _dirs)
      if(NOT _dir MATCHES "^/opt/python/")
        list(APPEND _kept "${_dir}")
      endif()
    endforeach()
    set_target_properties(${_target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${_kept}")
  endforeach()
endfunction()

cmake_language(DEFER DIRECTORY "${CMAKE_SOURCE_DIR}" CALL roadbev_drop_wheel_build_paths)
