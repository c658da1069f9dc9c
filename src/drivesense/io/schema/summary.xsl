<?xml version="1.0" encoding="UTF-8"?>
<!--
  drivesense: flatten an experiment file to a CSV summary, one row per channel.

  Columns: experiment_id, format_version, experimenters, measurement, interface,
  sensor, channel, units, sample_rate_hz, start_time_s, samples, duration_s,
  data_groups, encoding.  Text fields are quoted as in RFC 4180.
  Run with: drivesense xml transform FILE.xml (this sheet is the default)
-->
<xsl:stylesheet version="1.0"
                xmlns:xsl="http://www.w3.org/1999/XSL/Transform"
                xmlns:e="urn:drivesense:experiment:1">
  <xsl:output method="text" encoding="UTF-8"/>
  <xsl:strip-space elements="*"/>

  <xsl:template name="quote">
    <xsl:param name="text"/>
    <xsl:text>"</xsl:text>
    <xsl:call-template name="escape">
      <xsl:with-param name="text" select="$text"/>
    </xsl:call-template>
    <xsl:text>"</xsl:text>
  </xsl:template>

  <xsl:template name="escape">
    <xsl:param name="text"/>
    <xsl:choose>
      <xsl:when test="contains($text, '&quot;')">
        <xsl:value-of select="substring-before($text, '&quot;')"/>
        <xsl:text>""</xsl:text>
        <xsl:call-template name="escape">
          <xsl:with-param name="text" select="substring-after($text, '&quot;')"/>
        </xsl:call-template>
      </xsl:when>
      <xsl:otherwise>
        <xsl:value-of select="$text"/>
      </xsl:otherwise>
    </xsl:choose>
  </xsl:template>

  <xsl:template match="/">
    <xsl:text>experiment_id,format_version,experimenters,measurement,interface,sensor,channel,units,sample_rate_hz,start_time_s,samples,duration_s,data_groups,encoding&#10;</xsl:text>
    <xsl:apply-templates select="e:experimentResults/e:measurement/e:interface/e:sensor/e:channel"/>
  </xsl:template>

  <xsl:template match="e:channel">
    <xsl:variable name="root" select="ancestor::e:experimentResults"/>
    <xsl:variable name="m" select="ancestor::e:measurement"/>
    <xsl:call-template name="quote"><xsl:with-param name="text" select="$root/@id"/></xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:value-of select="$root/@formatVersion"/>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote">
      <xsl:with-param name="text">
        <xsl:for-each select="$root/e:personnel/e:experimenter">
          <xsl:if test="position() &gt; 1">; </xsl:if>
          <xsl:value-of select="@name"/>
        </xsl:for-each>
      </xsl:with-param>
    </xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote">
      <xsl:with-param name="text">
        <xsl:choose>
          <xsl:when test="$m/@name"><xsl:value-of select="$m/@name"/></xsl:when>
          <xsl:otherwise><xsl:value-of select="count($m/preceding-sibling::e:measurement) + 1"/></xsl:otherwise>
        </xsl:choose>
      </xsl:with-param>
    </xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote"><xsl:with-param name="text" select="ancestor::e:interface/@name"/></xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote"><xsl:with-param name="text" select="ancestor::e:sensor/@name"/></xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote"><xsl:with-param name="text" select="@name"/></xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:call-template name="quote"><xsl:with-param name="text" select="@units"/></xsl:call-template>
    <xsl:text>,</xsl:text>
    <xsl:value-of select="@sampleRate"/>
    <xsl:text>,</xsl:text>
    <xsl:choose>
      <xsl:when test="@startTime"><xsl:value-of select="@startTime"/></xsl:when>
      <xsl:otherwise>0</xsl:otherwise>
    </xsl:choose>
    <xsl:text>,</xsl:text>
    <xsl:value-of select="@samples"/>
    <xsl:text>,</xsl:text>
    <xsl:value-of select="@samples div @sampleRate"/>
    <xsl:text>,</xsl:text>
    <xsl:value-of select="count(e:dataGroup)"/>
    <xsl:text>,</xsl:text>
    <xsl:choose>
      <xsl:when test="e:dataGroup[1]/@encoding = 'text'">text</xsl:when>
      <xsl:otherwise>
        <xsl:text>base64 </xsl:text>
        <xsl:choose>
          <xsl:when test="e:dataGroup[1]/@dtype"><xsl:value-of select="e:dataGroup[1]/@dtype"/></xsl:when>
          <xsl:otherwise>float64</xsl:otherwise>
        </xsl:choose>
      </xsl:otherwise>
    </xsl:choose>
    <xsl:text>&#10;</xsl:text>
  </xsl:template>
</xsl:stylesheet>
