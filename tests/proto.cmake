# Control protocol: codec round trips and error codes; hostile input (fault label).
if(TARGET impasto_proto)
  impasto_test(test-proto LIBS impasto_proto)
  impasto_test(test-proto-hostile LABELS fault LIBS impasto_proto)
endif()
