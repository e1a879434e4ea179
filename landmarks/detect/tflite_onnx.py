"""Convert the small TFLite CNNs of MediaPipe's face detector, face mesh, iris net and selfie segmenter to ONNX
(conversion time only).

The graphs are plain convolutional nets: CONV_2D, DEPTHWISE_CONV_2D, PRELU / RELU, ADD, MAX_POOL_2D, PAD,
RESHAPE, CONCATENATION, with float16 weights behind DEQUANTIZE ops; the selfie segmenter adds HARD_SWISH,
LOGISTIC, AVERAGE_POOL_2D and MUL (its squeeze-and-excite blocks), RESIZE_BILINEAR and MediaPipe's custom
Convolution2DTransposeBias. This converter covers exactly that set and
refuses anything else by name, so a new op never converts silently wrong. Tensors are kept NCHW inside the
ONNX graph (onnxruntime's native layout): the NHWC input is transposed once at the start, and a tensor goes back
to NHWC only where an op's semantics need it (RESHAPE, CONCATENATION) and at the outputs, so every output has
the TFLite model's shape. float16 weights are widened to float32 here (fp32 is the runtime default).

Needs the ``tflite`` flatbuffer package (``pip install tflite``), which the runtime never imports.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from landmarks.exceptions import LandmarksError

_NHWC_TO_NCHW = (0, 3, 1, 2)
_NCHW_TO_NHWC = (0, 2, 3, 1)


class ConversionError(LandmarksError):
    """The TFLite graph uses something this converter does not translate."""


def _tflite() -> Any:
    try:
        import tflite
    except ImportError as exc:
        raise ConversionError("the converter needs the tflite flatbuffer package: `pip install tflite`") from exc
    return tflite


def _op_name(tflite: Any, model: Any, op: Any) -> str:
    code_table = model.OperatorCodes(op.OpcodeIndex())
    code = max(code_table.BuiltinCode(), code_table.DeprecatedBuiltinCode())
    for name, value in vars(tflite.BuiltinOperator).items():
        if value == code and not name.startswith("_"):
            return name
    return f"code {code}"


def _same_pads(size: int, kernel: int, stride: int, dilation: int = 1) -> tuple[int, int]:
    """TensorFlow's SAME padding (extra pixel at the end) as explicit (begin, end)."""
    effective = (kernel - 1) * dilation + 1
    out = -(-size // stride)
    total = max((out - 1) * stride + effective - size, 0)
    return total // 2, total - total // 2


class _Builder:
    """Walks the TFLite subgraph once, emitting ONNX nodes; tracks each tensor's layout ("nchw" or "nhwc")."""

    def __init__(self, model_bytes: bytes) -> None:
        tflite = _tflite()
        self.tflite = tflite
        self.model = tflite.Model.GetRootAsModel(model_bytes, 0)
        if self.model.SubgraphsLength() != 1:
            raise ConversionError(f"expected one subgraph, found {self.model.SubgraphsLength()}")
        self.graph = self.model.Subgraphs(0)
        self.nodes: list[Any] = []
        self.initializers: list[Any] = []
        self.constants: dict[int, np.ndarray] = {}  # tensor index -> folded float32 / int value
        self.names: dict[int, str] = {}  # tensor index -> ONNX value name (the layout in self.layouts)
        self.layouts: dict[int, str] = {}
        self.transposed: dict[tuple[int, str], str] = {}
        self._count = 0

    # -- tensors ---------------------------------------------------------------------------------
    def tensor(self, index: int) -> Any:
        return self.graph.Tensors(index)

    def shape(self, index: int) -> list[int]:
        return [int(v) for v in self.tensor(index).ShapeAsNumpy()]

    def buffer(self, index: int) -> np.ndarray | None:
        tensor = self.tensor(index)
        data = self.model.Buffers(tensor.Buffer()).DataAsNumpy()
        if isinstance(data, int) or data.size == 0:
            return None
        types = {
            self.tflite.TensorType.FLOAT32: np.float32,
            self.tflite.TensorType.FLOAT16: np.float16,
            self.tflite.TensorType.INT32: np.int32,
            self.tflite.TensorType.INT64: np.int64,
        }
        if tensor.Type() not in types:
            raise ConversionError(f"tensor {tensor.Name().decode()}: unsupported constant type {tensor.Type()}")
        if tensor.Quantization() is not None and tensor.Quantization().ScaleLength() > 0:
            raise ConversionError(f"tensor {tensor.Name().decode()} is quantized; only float16 weights are handled")
        return np.frombuffer(data.tobytes(), dtype=types[tensor.Type()]).reshape(self.shape(index))

    def constant(self, index: int) -> np.ndarray:
        if index not in self.constants:
            value = self.buffer(index)
            if value is None:
                raise ConversionError(f"tensor {self.tensor(index).Name().decode()} should be a constant")
            self.constants[index] = value.astype(np.float32) if value.dtype == np.float16 else value
        return self.constants[index]

    def fresh(self, stem: str) -> str:
        self._count += 1
        return f"{stem}_{self._count}"

    def add_initializer(self, stem: str, value: np.ndarray) -> str:
        from onnx import numpy_helper

        name = self.fresh(stem)
        self.initializers.append(numpy_helper.from_array(np.ascontiguousarray(value), name))
        return name

    def node(self, op_type: str, inputs: list[str], stem: str, **attrs: Any) -> str:
        from onnx import helper

        output = self.fresh(stem)
        self.nodes.append(helper.make_node(op_type, inputs, [output], name=output, **attrs))
        return output

    def value(self, index: int, layout: str) -> str:
        """The ONNX name of tensor ``index`` in ``layout``, transposing (once, cached) when it is held in the other."""
        held = self.layouts[index]
        if held == layout or len(self.shape(index)) != 4:
            return self.names[index]
        if (index, layout) not in self.transposed:  # one transposed copy per tensor and layout
            perm = _NCHW_TO_NHWC if layout == "nhwc" else _NHWC_TO_NCHW
            self.transposed[index, layout] = self.node("Transpose", [self.names[index]], f"t{index}", perm=list(perm))
        return self.transposed[index, layout]

    def set(self, index: int, name: str, layout: str) -> None:
        self.names[index], self.layouts[index] = name, layout

    # -- ops -------------------------------------------------------------------------------------
    def activation(self, name: str, code: int) -> str:
        act = self.tflite.ActivationFunctionType
        if code == act.NONE:
            return name
        if code == act.RELU:
            return self.node("Relu", [name], "relu")
        if code == act.RELU6:
            return self.node("Clip", [name, self.add_initializer("zero", np.float32(0)),
                                      self.add_initializer("six", np.float32(6))], "relu6")
        raise ConversionError(f"fused activation {code} is not handled")

    def options(self, op: Any, cls_name: str) -> Any:
        table = op.BuiltinOptions()
        options = getattr(self.tflite, cls_name)()
        options.Init(table.Bytes, table.Pos)
        return options

    def conv(self, op: Any, depthwise: bool) -> None:
        inputs = op.InputsAsNumpy()
        source, weights_index = int(inputs[0]), int(inputs[1])
        options = self.options(op, "DepthwiseConv2DOptions" if depthwise else "Conv2DOptions")
        weights = self.constant(weights_index)  # conv: (O, kh, kw, I); depthwise: (1, kh, kw, C * multiplier)
        _, height, width, channels = self.shape(source)
        if depthwise:
            if options.DepthMultiplier() not in (0, 1):
                raise ConversionError("depthwise multiplier > 1 is not handled")
            kernel = weights.transpose(3, 0, 1, 2)  # (C, 1, kh, kw)
            group = channels
        else:
            kernel = weights.transpose(0, 3, 1, 2)  # (O, I, kh, kw)
            group = 1
        kh, kw = kernel.shape[2:]
        stride = (options.StrideH(), options.StrideW())
        dilation = (options.DilationHFactor(), options.DilationWFactor())
        if options.Padding() == self.tflite.Padding.SAME:
            top, bottom = _same_pads(height, kh, stride[0], dilation[0])
            left, right = _same_pads(width, kw, stride[1], dilation[1])
        else:
            top = bottom = left = right = 0
        names = [self.value(source, "nchw"), self.add_initializer("w", kernel)]
        if len(inputs) > 2 and inputs[2] >= 0:
            names.append(self.add_initializer("b", self.constant(int(inputs[2]))))
        out = self.node("Conv", names, "conv", kernel_shape=[kh, kw], strides=list(stride),
                        dilations=list(dilation), pads=[top, left, bottom, right], group=group)
        self.set(int(op.Outputs(0)), self.activation(out, options.FusedActivationFunction()), "nchw")

    def pool(self, op: Any, onnx_op: str, **attrs: Any) -> None:
        """MAX_POOL_2D / AVERAGE_POOL_2D with TFLite's padding made explicit (``attrs``: extra ONNX attributes)."""
        source = int(op.Inputs(0))
        options = self.options(op, "Pool2DOptions")
        kh, kw = options.FilterHeight(), options.FilterWidth()
        stride = (options.StrideH(), options.StrideW())
        _, height, width, _ = self.shape(source)
        if options.Padding() == self.tflite.Padding.SAME:
            top, bottom = _same_pads(height, kh, stride[0])
            left, right = _same_pads(width, kw, stride[1])
        else:
            top = bottom = left = right = 0
        out = self.node(onnx_op, [self.value(source, "nchw")], "pool" if onnx_op == "MaxPool" else "avgpool",
                        kernel_shape=[kh, kw], strides=list(stride), pads=[top, left, bottom, right], **attrs)
        self.set(int(op.Outputs(0)), self.activation(out, options.FusedActivationFunction()), "nchw")

    def add(self, op: Any) -> None:
        first, second = int(op.Inputs(0)), int(op.Inputs(1))
        if self.shape(first) != self.shape(second):
            raise ConversionError("ADD with broadcasting is not handled")
        layout = self.layouts[first]
        out = self.node("Add", [self.value(first, layout), self.value(second, layout)], "add")
        options = self.options(op, "AddOptions")
        self.set(int(op.Outputs(0)), self.activation(out, options.FusedActivationFunction()), layout)

    def prelu(self, op: Any) -> None:
        """PReLU as relu(x) - slope * relu(-x): the same values (the slopes may be negative or above 1, so no max
        trick), and onnxruntime's PRelu kernel broadcasts the per-channel slope slowly (the face mesh net: 4.4 ->
        2.7 ms on one thread, PRelu 2.6 ms of it)."""
        source, alpha_index = int(op.Inputs(0)), int(op.Inputs(1))
        alpha = self.constant(alpha_index)  # (1, 1, C) or (C,)
        slope = alpha.reshape(-1)[:, None, None]  # (C, 1, 1): broadcasts over NCHW
        x = self.value(source, "nchw")
        positive = self.node("Relu", [x], "prelu_positive")
        negative = self.node("Relu", [self.node("Neg", [x], "prelu_negated")], "prelu_negative")
        scaled = self.node("Mul", [negative, self.add_initializer("alpha", slope)], "prelu_scaled")
        self.set(int(op.Outputs(0)), self.node("Sub", [positive, scaled], "prelu"), "nchw")

    def unary(self, op: Any, onnx_op: str) -> None:
        """An elementwise op of one input (RELU, HARD_SWISH, LOGISTIC), in whatever layout its input is held."""
        source = int(op.Inputs(0))
        layout = self.layouts[source]
        self.set(int(op.Outputs(0)), self.node(onnx_op, [self.value(source, layout)], onnx_op.lower()), layout)

    def mul(self, op: Any) -> None:
        """MUL of two tensors of rank 4 (broadcasting as numpy does: both held NCHW) or of a tensor and a constant."""
        first, second = int(op.Inputs(0)), int(op.Inputs(1))
        names = []
        for index in (first, second):
            if index in self.names:
                names.append(self.value(index, "nchw") if len(self.shape(index)) == 4 else self.names[index])
            else:  # a constant: NHWC -> NCHW for rank 4, else broadcast over the channels last as TFLite does
                value = self.constant(index)
                value = value.transpose(_NHWC_TO_NCHW) if value.ndim == 4 else value.reshape(-1)[:, None, None]
                names.append(self.add_initializer("mul", value.astype(np.float32)))
        out = self.node("Mul", names, "mul")
        options = self.options(op, "MulOptions")
        self.set(int(op.Outputs(0)), self.activation(out, options.FusedActivationFunction()), "nchw")

    def resize_bilinear(self, op: Any) -> None:
        source, target = int(op.Inputs(0)), int(op.Outputs(0))
        options = self.options(op, "ResizeBilinearOptions")
        if options.AlignCorners():
            mode = "align_corners"
        elif options.HalfPixelCenters():
            mode = "half_pixel"
        else:
            mode = "asymmetric"  # TFLite's default: source = destination x scale
        _, height, width, channels = self.shape(target)
        sizes = self.add_initializer("sizes", np.array([1, channels, height, width], np.int64))
        out = self.node("Resize", [self.value(source, "nchw"), "", "", sizes], "resize", mode="linear",
                        coordinate_transformation_mode=mode)
        self.set(target, out, "nchw")

    def transpose_conv_bias(self, op: Any) -> None:
        """MediaPipe's custom Convolution2DTransposeBias (its options: padding, stride width, stride height as int32;
        weights (O, kh, kw, I), bias (O,)) as ONNX ConvTranspose with the TFLite output's size."""
        source, weights_index, bias_index = (int(v) for v in op.InputsAsNumpy()[:3])
        padding, stride_w, stride_h = np.frombuffer(op.CustomOptionsAsNumpy().tobytes(), np.int32)[:3]
        kernel = self.constant(weights_index).transpose(3, 0, 1, 2)  # (I, O, kh, kw)
        _, height, width, _ = self.shape(int(op.Outputs(0)))
        _, in_height, in_width, _ = self.shape(source)
        kh, kw = kernel.shape[2:]
        if padding == self.tflite.Padding.VALID or (kh <= stride_h and kw <= stride_w):
            total = (0, 0)
        else:
            total = (max((in_height - 1) * stride_h + kh - height, 0), max((in_width - 1) * stride_w + kw - width, 0))
        pads = [total[0] // 2, total[1] // 2, total[0] - total[0] // 2, total[1] - total[1] // 2]
        out = self.node("ConvTranspose", [self.value(source, "nchw"), self.add_initializer("w", kernel),
                                          self.add_initializer("b", self.constant(bias_index))], "deconv",
                        kernel_shape=[int(kh), int(kw)], strides=[int(stride_h), int(stride_w)], pads=pads)
        self.set(int(op.Outputs(0)), out, "nchw")

    def pad(self, op: Any) -> None:
        source = int(op.Inputs(0))
        paddings = self.constant(int(op.Inputs(1))).astype(np.int64)  # (4, 2) NHWC (begin, end)
        nchw = paddings[list(_NHWC_TO_NCHW)]
        pads = np.concatenate([nchw[:, 0], nchw[:, 1]])
        out = self.node("Pad", [self.value(source, "nchw"), self.add_initializer("pads", pads)], "pad")
        self.set(int(op.Outputs(0)), out, "nchw")

    def reshape(self, op: Any) -> None:
        source, target = int(op.Inputs(0)), int(op.Outputs(0))
        shape = np.array(self.shape(target), np.int64)
        out = self.node("Reshape", [self.value(source, "nhwc"), self.add_initializer("shape", shape)], "reshape")
        self.set(target, out, "nhwc")

    def concat(self, op: Any) -> None:
        options = self.options(op, "ConcatenationOptions")
        sources = [int(v) for v in op.InputsAsNumpy()]
        out = self.node("Concat", [self.value(s, "nhwc") for s in sources], "concat", axis=int(options.Axis()))
        self.set(int(op.Outputs(0)), self.activation(out, options.FusedActivationFunction()), "nhwc")

    # -- whole graph -----------------------------------------------------------------------------
    def build(self, graph_name: str) -> Any:
        from onnx import TensorProto, helper

        if self.graph.InputsLength() != 1:
            raise ConversionError("expected one input")
        input_index = int(self.graph.Inputs(0))
        input_name = self.tensor(input_index).Name().decode()
        self.set(input_index, input_name, "nhwc")
        handlers = {
            "CONV_2D": lambda op: self.conv(op, depthwise=False),
            "DEPTHWISE_CONV_2D": lambda op: self.conv(op, depthwise=True),
            "MAX_POOL_2D": lambda op: self.pool(op, "MaxPool"),
            "ADD": self.add,
            "PRELU": self.prelu,
            "RELU": lambda op: self.unary(op, "Relu"),
            "PAD": self.pad,
            "RESHAPE": self.reshape,
            "CONCATENATION": self.concat,
            "HARD_SWISH": lambda op: self.unary(op, "HardSwish"),
            "LOGISTIC": lambda op: self.unary(op, "Sigmoid"),
            # TFLite's SAME padding averages over the pixels inside only
            "AVERAGE_POOL_2D": lambda op: self.pool(op, "AveragePool", count_include_pad=0),
            "MUL": self.mul,
            "RESIZE_BILINEAR": self.resize_bilinear,
        }
        for position in range(self.graph.OperatorsLength()):
            op = self.graph.Operators(position)
            name = _op_name(self.tflite, self.model, op)
            if name == "DEQUANTIZE":  # float16 weight -> float32: folded into the constant it feeds
                self.constants[int(op.Outputs(0))] = self.constant(int(op.Inputs(0)))
                continue
            if name == "CUSTOM":
                custom = self.model.OperatorCodes(op.OpcodeIndex()).CustomCode().decode()
                if custom != "Convolution2DTransposeBias":
                    raise ConversionError(f"TFLite custom op {custom} is not handled by this converter")
                self.transpose_conv_bias(op)
                continue
            if name not in handlers:
                raise ConversionError(f"TFLite op {name} is not handled by this converter")
            handlers[name](op)
        outputs = []
        for position in range(self.graph.OutputsLength()):
            index = int(self.graph.Outputs(position))
            out_name = self.tensor(index).Name().decode()
            self.nodes.append(helper.make_node("Identity", [self.value(index, "nhwc")], [out_name], name=out_name))
            outputs.append(helper.make_tensor_value_info(out_name, TensorProto.FLOAT, self.shape(index)))
        inputs = [helper.make_tensor_value_info(input_name, TensorProto.FLOAT, self.shape(input_index))]
        graph = helper.make_graph(self.nodes, graph_name, inputs, outputs, self.initializers)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="lsr-tflite-onnx")
        model.ir_version = 8  # onnxruntime >= 1.17 reads IR 8
        return model


def convert(tflite_path: str | Path, graph_name: str | None = None) -> Any:
    """Read a ``.tflite`` file and return the equivalent ``onnx.ModelProto`` (checked by onnx's checker)."""
    import onnx

    path = Path(tflite_path)
    model = _Builder(path.read_bytes()).build(graph_name or path.stem)
    onnx.checker.check_model(model)
    return model
