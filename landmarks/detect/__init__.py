"""Faces found and followed, behind one interface (``face_detector.FaceDetector``):

* ``mediapipe_mesh`` / ``mediapipe_tracker``: MediaPipe's BlazeFace and 468-point mesh on onnxruntime (the default);
* ``face_detector`` / ``dlib_tracker`` / ``dlib_models``: dlib's HOG / CNN detector and 68-point shape predictor;
* ``registry``: either one by name (``make_detector``, ``make_tracker``);
* ``same_person``: whether two faces are the same person;
* ``tflite_onnx`` / ``rebuild_mediapipe``: how the shipped MediaPipe nets were rebuilt as ONNX.
"""
